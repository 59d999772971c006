"""Train the AgentFormer CVAE with a ForceFormer input variant on one leave-one-out benchmark.

Reads: windows and, for the dr and re variants, the forces arrays they use (`fftool.variants.SPECS`).
Training goals are the ground truth, or, for goal variants with `goal_training.source = "module"`, the
ground truth moved by the goal module's own errors (`learning.goal_errors`, from the goals artifact's
validation part); with `"fair"`, the best-of-K samples decode the module's goal sets. With either, or with
`goal_training.fair_best_epoch`, the best epoch is chosen under the fair protocol on validation. Writes:
`cvae/<fp>/model.pt` (best weights by validation minADE, the resolved config, everything needed to rebuild
the model),
`log.csv` and the same per-epoch curves as TensorBoard events in `tensorboard/` (written live to the
scratch folder while training: `tensorboard --logdir <root>`). Run: `fftool train-cvae --benchmarks zara1 --variant dr`.

Many windows are batched per optimizer step (padded agents, masked attention and losses) instead of
the official one-window-at-a-time loop. A checkpoint is written after every epoch to the store's
scratch folder; every epoch reseeds from (seed, epoch), so a run killed mid-epoch and started again
redoes that epoch and ends with the same weights as an uninterrupted run.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Final

import numpy as np
import torch

from fftool.artifacts.schema import COMMANDS, CVAE_LOG_FILE, CVAE_MODEL_FILE, VERSIONS
from fftool.artifacts.store import Artifact
from fftool.config import CVAEConfig, ForcesConfig, GoalTrainingConfig, PipelineConfig
from fftool.errors import FftoolError
from fftool.learning import distributed, goal_errors
from fftool.learning.batches import SceneSet, load_scene_set
from fftool.learning.cvae_model import (
    Trained,
    build_model,
    epoch_plan,
    fair_best_of_k,
    training_loss,
    val_windows,
    validate,
)
from fftool.learning.features import prepare, training_inputs
from fftool.learning.sampling import fair_min_ade_fde
from fftool.learning.training import (
    Schedule,
    Step,
    epoch_seed,
    fit,
    generator,
    make_optimizer,
    save_checkpoint,
    seed_all,
)
from fftool.models.forceformer import ForceFormer
from fftool.stages.contract import Reads, Stage, StageContext
from fftool.variants import SPECS, reads_goal

NAME: Final = "cvae"


def _rows(index: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """The windows `index` of a batch field."""
    return values[index]


@dataclass
class _Trainer:
    """The CVAE's part of `training.fit`: the steps of an epoch of batched windows under AgentFormer's loss,
    throughput columns, and the validation minADE/minFDE whose minADE picks the best epoch."""

    cfg: CVAEConfig
    forces_cfg: ForcesConfig | None  # None for variants without forces (baseline, goal)
    model: ForceFormer
    optimizer: torch.optim.Optimizer
    train: SceneSet
    val: SceneSet
    val_subset: np.ndarray
    obs_len: int
    dt_s: float | None
    per_epoch: int  # training windows per epoch
    device: torch.device
    module: goal_errors.ModuleGoals | None = None  # training goals as wrong as the module's; fair validation
    terms: tuple[str, ...] = ("loss", "recon", "kl", "best_of_k", "kl_unclamped")  # LossParts, `total` as "loss"
    schedule: Schedule = field(init=False)
    net: torch.nn.Module = field(init=False)  # the model, in DistributedDataParallel under torchrun

    def __post_init__(self) -> None:
        cfg = self.cfg
        steps = tuple(len(epoch_plan(self.train, cfg, epoch, self.per_epoch)[0]) for epoch in range(cfg.epochs))
        self.schedule = Schedule(cfg.lr, cfg.schedule, steps, cfg.warmup_fraction, cfg.decay_every, cfg.decay_gamma)
        self.net = distributed.wrap(self.model, self.device)

    @property
    def grad_clip(self) -> float:
        return self.cfg.grad_clip

    def steps(self, epoch: int) -> tuple[int, Iterator[Step]]:
        """The (seed, epoch) plan's steps.

        Under torchrun every rank draws the same plan and builds the same global batch (agent caps included),
        then trains on its windows (`distributed.shard`) with its loss scaled so that the averaged gradient is
        the global batch's; rotations and latent samples come from the rank's own generator."""
        cfg, device = self.cfg, self.device
        gen = generator(distributed.rank_seed(epoch_seed(cfg.seed, epoch)), device)
        plan, rng = epoch_plan(self.train, cfg, epoch, self.per_epoch)
        warm = epoch < cfg.best_of_k_warmup_epochs  # fftool's option: the posterior first, then the full loss

        def each() -> Iterator[Step]:
            for members in plan:
                batch, share = self.train.batch(members, cfg.max_agents, rng), 1.0
                seen = int(batch.agent_mask.sum())
                if distributed.active():
                    mine, share = distributed.shard(members)
                    batch = batch.map(partial(_rows, torch.as_tensor(mine)))
                batch, goal = batch.to(device), None
                fair = self.module is not None and self.module.source == "fair"
                if self.module is not None and self.module.source == "module":  # goals as wrong as the module's
                    batch, goal = self.module.move(batch, self.obs_len, gen, self.forces_cfg, self.dt_s, cfg.variant)
                prepared = prepare(batch, cfg.variant, self.obs_len, goal=goal, rotate=cfg.rotate, generator=gen)
                own_samples = not warm and not fair
                parts = training_loss(self.net, prepared, cfg, self.forces_cfg, self.dt_s, gen, best_of_k=own_samples)
                if fair and not warm:  # the best-of-K samples decode the module's goal sets, sample k goal k
                    assert self.module is not None
                    sets = self.module.errors.draw_sets(batch.xy, self.obs_len, gen, cfg.train_k)
                    term = fair_best_of_k(self.model, batch, sets, cfg, self.forces_cfg, self.dt_s, self.obs_len, gen)
                    parts = parts._replace(total=parts.total + term, best_of_k=term)
                if distributed.active():
                    yield Step(parts.total * share, tuple(parts), share / distributed.world_size(), seen)
                else:
                    yield Step(parts.total, tuple(parts), 1.0, seen)

        return len(plan), each()

    def columns(
        self, epoch: int, sums: dict[str, float], seen: int, seconds: float, previous: dict[str, Any] | None
    ) -> dict[str, Any]:
        """Throughput (totals carried on from `previous`), the last learning rate and the mean loss terms."""
        before = previous or {"agent_windows_seen": 0, "train_seconds": 0.0}
        return {
            "train_seconds": round(float(before["train_seconds"]) + seconds, 3),
            "agent_windows_seen": int(before["agent_windows_seen"]) + seen,
            "agent_windows_per_s": round(seen / seconds, 2),
            "lr": self.optimizer.param_groups[0]["lr"],
            **{f"train_{name}": value for name, value in sums.items()},
        }

    def validate(self) -> dict[str, float]:
        """minADE_K and minFDE_K of the fixed validation subset (with true goals), and, with the goal module's
        goals, under the fair protocol."""
        cfg = self.cfg
        found = validate(
            self.model, self.val, self.val_subset, cfg, self.forces_cfg, self.dt_s, self.obs_len, self.device
        )
        ade, fde = found.pop("min_ade"), found.pop("min_fde")
        fair = {}
        if self.module is not None:
            # the force constants as the saved model keeps them (evaluate's view of it): the declared ones
            forces = None if self.forces_cfg is None else ForcesConfig.model_validate(self.forces_cfg.model_dump())
            trained = Trained(self.model, cfg, forces, self.dt_s)
            found_ade, found_fde = fair_min_ade_fde(
                trained, self.val, self.val_subset, self.module.val_goals, self.obs_len, cfg.k, cfg.seed
            )
            fair = {f"val_fair_min_ade@{cfg.k}_m": found_ade, f"val_fair_min_fde@{cfg.k}_m": found_fde}
        return {
            f"val_min_ade@{cfg.k}_m": ade,
            f"val_min_fde@{cfg.k}_m": fde,
            **fair,
            **{f"val_{k}": v for k, v in found.items()},
        }


def _trainer(
    cfg: CVAEConfig,
    forces_cfg: ForcesConfig,
    benchmark: str,
    windows: Artifact,
    forces: Artifact | None,
    device: torch.device,
    goal_training: GoalTrainingConfig | None = None,
    goals: Artifact | None = None,
) -> _Trainer:
    """The benchmark's scenes with the forces the variant reads, and a fresh model seeded by the run's seed;
    with the goal module's goals (`goals`), its errors for training and its validation goals."""
    reads = SPECS[cfg.variant].training_reads
    train = load_scene_set(windows, forces, benchmark, "train", cfg.train_stride, reads)
    val = load_scene_set(windows, forces, benchmark, "val", reads=reads)
    val_subset = val_windows(val, cfg)
    obs_len = int(windows.manifest.stats["obs_len"])
    module = None
    if goals is not None and goal_training is not None:
        if goal_training.source == "fair" and distributed.active():
            raise FftoolError('goal_training.source = "fair" trains in one process: run it without torchrun')
        module = goal_errors.module_goals(goals, val, benchmark, obs_len, goal_training, device)
    seed_all(cfg.seed)
    model = build_model(cfg).to(device)
    return _Trainer(
        cfg=cfg,
        forces_cfg=forces_cfg if forces is not None else None,
        model=model,
        optimizer=make_optimizer(model, cfg.optimizer, cfg.lr, cfg.weight_decay),
        train=train,
        val=val,
        val_subset=val_subset,
        obs_len=obs_len,
        dt_s=float(forces.manifest.stats["dt_s"]) if forces is not None else None,  # the forces' time step
        per_epoch=min(train.windows, cfg.max_train_windows) if cfg.max_train_windows else train.windows,
        device=device,
        module=module,
    )


def train(
    cfg: CVAEConfig,
    forces_cfg: ForcesConfig,
    windows: Artifact,
    forces: Artifact | None,
    ctx: StageContext,
    goal_training: GoalTrainingConfig | None = None,
    goals: Artifact | None = None,
) -> dict[str, Any]:
    """Train with validation every epoch; write the best model and the log; return the manifest stats.

    cfg: the `cvae` section (variant included); forces_cfg: the force constants used in the decoder;
    windows, forces: input artifacts (no forces for the baseline and goal variants); ctx: the benchmark,
    build and scratch folders, device, callbacks; goal_training, goals: for goal variants trained with the
    goal module's errors, the section and the goals artifact (the best epoch is then the fair one).
    """
    benchmark, device, out_dir = ctx.need_benchmark(), distributed.device(ctx.device()), ctx.dir
    trainer = _trainer(cfg, forces_cfg, benchmark, windows, forces, device, goal_training, goals)
    fair = "_fair" if trainer.module is not None else ""
    started, best_by = time.perf_counter(), f"val{fair}_min_ade@{cfg.k}_m"
    progress = fit(trainer, ctx, seed=cfg.seed, best_by=best_by, log_name=CVAE_LOG_FILE)
    save_checkpoint(
        out_dir / CVAE_MODEL_FILE,
        {
            "state_dict": progress.best_state,
            "config": cfg.model_dump(mode="json"),
            "forces_config": None if trainer.forces_cfg is None else trainer.forces_cfg.model_dump(mode="json"),
            "benchmark": benchmark,
            "best_epoch": progress.best_epoch,
            "dt_s": trainer.dt_s,
            "obs_len": trainer.obs_len,
        },
    )
    return progress.stats(benchmark, device, best_by, time.perf_counter() - started) | {
        "variant": cfg.variant,
        "train_windows": trainer.train.windows,
        "train_windows_per_epoch": trainer.per_epoch,
        "val_windows": len(trainer.val_subset),
        "parameters": sum(p.numel() for p in trainer.model.parameters()),
    }


def build(cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: StageContext) -> dict[str, Any]:
    """The stage contract: train one benchmark's CVAE of the configured variant (the force constants its
    decoder reads come with the forces arrays it declares)."""
    forces, goals = inputs.get("forces"), inputs.get("goals")
    goal_training = cfg.goal_training if goals is not None else None
    return train(
        cfg.cvae, cfg.forces if forces is not None else None, inputs["windows"], forces, ctx, goal_training, goals
    )


def declare(cfg: PipelineConfig) -> Reads:
    """The cvae section, the windows and, for dr and re, the forces arrays the variant trains on."""
    variant = cfg.cvae.variant
    if reads_goal(variant) and cfg.goal_training.reads_module():  # the goal module's goals and errors
        artifacts = training_inputs(variant) | {"goals": None}
        return Reads(params=("cvae.*", "goal_training.*"), artifacts=artifacts, command=f" --variant {variant}")
    return Reads(params=("cvae.*",), artifacts=training_inputs(variant), command=f" --variant {variant}")


STAGE = Stage(
    NAME,
    VERSIONS[NAME],
    COMMANDS[NAME],
    label="train CVAE",
    declare=declare,
    build=build,
    section="cvae",
    per_benchmark=True,
    distributed=True,
)
