"""Train AgentFormer's DLow sampler (its second stage) over a trained CVAE of one benchmark and variant.

Reads: the `cvae` artifact (frozen, in eval mode: no dropout, no scene rotation, no agent cap), windows and,
for dr and re, the forces arrays the CVAE trained on. Training goals are those of the CVAE's training: the
ground truth, or, over a CVAE trained for the goal module's goals (`goal_training.source = "module"`), goals
moved by the module's errors; the best epoch is chosen under the fair protocol over any CVAE whose training
read the goal module (`GoalTrainingConfig.reads_module`). Writes:
`dlow/<fp>/model.pt` (the Q-net's best weights by validation minADE of its K codes),
`log.csv` and the same curves as TensorBoard events. Run: `fftool train-dlow --benchmarks zara1 --variant
baseline`. `evaluate`, `predict` and the API then draw their K futures from its codes z = b instead of the
prior (AgentFormer's test-time sampler; docs/cvae.md "DLow").
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import torch

from fftool.artifacts.schema import COMMANDS, DLOW_LOG_FILE, DLOW_MODEL_FILE, VERSIONS
from fftool.artifacts.store import Artifact
from fftool.config import DLowConfig, GoalTrainingConfig, PipelineConfig
from fftool.learning.batches import SceneSet, load_scene_set
from fftool.learning.cvae_model import Trained, load_model, sample, val_metrics
from fftool.learning.dlow_model import Preset, build_sampler, preset, training_loss
from fftool.learning.features import prepare, training_inputs
from fftool.learning.goal_errors import ModuleGoals, module_goals
from fftool.learning.sampling import fair_min_ade_fde
from fftool.learning.training import (
    Schedule,
    Step,
    epoch_batches,
    epoch_seed,
    fit,
    generator,
    save_checkpoint,
    seed_all,
    validation_subset,
)
from fftool.models.dlow import QNet
from fftool.stages.contract import Reads, Stage, StageContext
from fftool.variants import SPECS, reads_goal

NAME: Final = "dlow"


@dataclass
class _Trainer:
    """The DLow sampler's part of `training.fit`: the steps of an epoch of batched windows through the frozen
    CVAE under DLow's loss, and the validation minADE/minFDE of the K codes, whose minADE picks the best epoch."""

    cfg: DLowConfig
    chosen: Preset
    trained: Trained
    model: QNet  # what `fit` trains and checkpoints: the sampler alone
    optimizer: torch.optim.Optimizer
    train: SceneSet
    val: SceneSet
    val_subset: np.ndarray
    obs_len: int
    per_epoch: int
    device: torch.device
    module: ModuleGoals | None = None  # over a CVAE trained for the goal module's goals: the same goals
    terms: tuple[str, ...] = ("loss", "recon", "diverse", "kl", "kl_unclamped")  # DLowLossParts, `total` as "loss"
    schedule: Schedule = field(init=False)

    def __post_init__(self) -> None:
        cfg = self.cfg
        steps = tuple(len(self._plan(epoch)[0]) for epoch in range(cfg.epochs))
        self.schedule = Schedule(
            cfg.lr, self.chosen.schedule, steps, 0.0, cfg.decay_every, cfg.decay_gamma, cfg.lr_fix_epochs
        )  # fmt: skip

    @property
    def grad_clip(self) -> float:
        return self.cfg.grad_clip

    def _plan(self, epoch: int) -> tuple[list[np.ndarray], np.random.Generator]:
        cfg = self.cfg
        return epoch_batches(self.train, cfg.seed, epoch, self.per_epoch, cfg.batch_windows, cfg.max_agent_pairs)

    def steps(self, epoch: int) -> tuple[int, Iterator[Step]]:
        cfg, device, variant, trained = self.cfg, self.device, self.trained.config.variant, self.trained
        gen = generator(epoch_seed(cfg.seed, epoch), device)
        plan, _ = self._plan(epoch)

        def each() -> Iterator[Step]:
            for members in plan:
                batch, goal = self.train.batch(members).to(device), None
                if self.module is not None and self.module.source == "module":
                    batch, goal = self.module.move(
                        batch, self.obs_len, gen, trained.forces_config, trained.dt_s, variant
                    )
                prepared = prepare(batch, variant, self.obs_len, goal=goal)
                parts = training_loss(trained, self.model, prepared, cfg, self.chosen, gen)
                yield Step(parts.total, tuple(parts))

        return len(plan), each()

    def columns(
        self, epoch: int, sums: dict[str, float], seen: int, seconds: float, previous: dict[str, Any] | None
    ) -> dict[str, Any]:
        before = previous or {"train_seconds": 0.0}
        return {
            "train_seconds": round(float(before["train_seconds"]) + seconds, 3),
            "lr": self.optimizer.param_groups[0]["lr"],
            **{f"train_{name}": value for name, value in sums.items()},
        }

    def validate(self) -> dict[str, float]:
        """minADE_K and minFDE_K of the K codes on the fixed validation subset with ground-truth goals and,
        over a CVAE trained for the goal module's goals, under the fair protocol."""
        self.model.eval()
        model, cvae_cfg = self.trained.model, self.trained.config
        forces_cfg, dt_s, k = self.trained.forces_config, self.trained.dt_s, self.cfg.k
        ade, fde = val_metrics(
            self.val,
            self.val_subset,
            cvae_cfg,
            self.obs_len,
            self.device,
            lambda prepared: sample(model, prepared, cvae_cfg, forces_cfg, dt_s, k, sampler=self.model),
        )
        found = {f"val_min_ade@{k}_m": ade, f"val_min_fde@{k}_m": fde}
        if self.module is not None:
            fair_ade, fair_fde = fair_min_ade_fde(
                self.trained, self.val, self.val_subset, self.module.val_goals, self.obs_len, k, self.cfg.seed,
                sampler=self.model,
            )  # fmt: skip
            found |= {f"val_fair_min_ade@{k}_m": fair_ade, f"val_fair_min_fde@{k}_m": fair_fde}
        self.model.train()
        return found


def train(
    cfg: DLowConfig,
    windows: Artifact,
    forces: Artifact | None,
    cvae: Artifact,
    ctx: StageContext,
    goal_training: GoalTrainingConfig | None = None,
    goals: Artifact | None = None,
) -> dict:
    """Train the sampler with validation every epoch; write the best weights and the log; the manifest stats.
    goal_training, goals: over a CVAE trained for the goal module's goals, its section and the goals artifact
    (training goals drawn the same way; the best epoch is then the fair one)."""
    benchmark, device = ctx.need_benchmark(), ctx.device()
    trained = load_model(cvae, device)
    trained.model.requires_grad_(False)  # frozen, and in eval mode (load_model)
    reads = SPECS[trained.config.variant].training_reads
    train_set = load_scene_set(windows, forces, benchmark, "train", cfg.train_stride, reads)
    val = load_scene_set(windows, forces, benchmark, "val", reads=reads)
    seed_all(cfg.seed)
    sampler = build_sampler(trained.config, cfg).to(device)
    trainer = _Trainer(
        cfg=cfg,
        chosen=preset(benchmark),
        trained=trained,
        model=sampler,
        optimizer=torch.optim.Adam(sampler.parameters(), lr=cfg.lr),
        train=train_set,
        val=val,
        val_subset=validation_subset(val.windows, cfg.val_max_windows, cfg.seed),
        obs_len=int(windows.manifest.stats["obs_len"]),
        per_epoch=min(train_set.windows, cfg.max_train_windows) if cfg.max_train_windows else train_set.windows,
        device=device,
        module=None if goals is None or goal_training is None else module_goals(
            goals, val, benchmark, int(windows.manifest.stats["obs_len"]), goal_training, device
        ),
    )  # fmt: skip
    fair = "_fair" if trainer.module is not None else ""
    started, best_by = time.perf_counter(), f"val{fair}_min_ade@{cfg.k}_m"
    progress = fit(trainer, ctx, seed=cfg.seed, best_by=best_by, log_name=DLOW_LOG_FILE)
    save_checkpoint(
        ctx.dir / DLOW_MODEL_FILE,
        {
            "state_dict": progress.best_state,
            "d_model": trained.config.d_model,
            "z_dim": trained.config.z_dim,
            "k": cfg.k,
            "hidden": list(cfg.qnet_hidden),
            "config": cfg.model_dump(mode="json"),
            "benchmark": benchmark,
            "best_epoch": progress.best_epoch,
        },
    )
    return progress.stats(benchmark, device, best_by, time.perf_counter() - started) | {
        "variant": trained.config.variant,
        "preset": vars(trainer.chosen),
        "train_windows": train_set.windows,
        "train_windows_per_epoch": trainer.per_epoch,
        "val_windows": len(trainer.val_subset),
        "parameters": sum(p.numel() for p in sampler.parameters()),
    }


def build(cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: StageContext) -> dict[str, Any]:
    """The stage contract: train one benchmark's DLow sampler over its CVAE of the configured variant."""
    goals = inputs.get("goals")
    goal_training = cfg.goal_training if goals is not None else None
    return train(cfg.dlow, inputs["windows"], inputs.get("forces"), inputs["cvae"], ctx, goal_training, goals)


def declare(cfg: PipelineConfig) -> Reads:
    """The dlow settings, the CVAE it samples and the data that CVAE trained on."""
    variant = cfg.cvae.variant
    params = tuple(f"dlow.{key}" for key in DLowConfig.model_fields if key != "variants")  # evaluations read it
    artifacts = training_inputs(variant) | {"cvae": None}
    if reads_goal(variant) and cfg.goal_training.reads_module():  # as its CVAE: the module's goals and errors
        params, artifacts = (*params, "goal_training.*"), artifacts | {"goals": None}
    return Reads(params=params, artifacts=artifacts, command=f" --variant {variant}")


STAGE = Stage(
    NAME,
    VERSIONS[NAME],
    COMMANDS[NAME],
    label="train DLow",
    declare=declare,
    build=build,
    section="dlow",
    per_benchmark=True,
)
