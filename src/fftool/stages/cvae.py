"""Train the AgentFormer CVAE with a ForceFormer input variant on one leave-one-out benchmark.

Reads: windows and, for the dr and re variants, the forces arrays they use (`features.TRAINING_READS`;
training goals are the ground truth). Writes: `cvae/<fp>/model.pt` (best
weights by validation minADE, the resolved config, everything needed to rebuild the model),
`log.csv` and the same per-epoch curves as TensorBoard events in `tensorboard/` (written live to the
scratch folder while training: `tensorboard --logdir <root>`). Run: `fftool train-cvae --benchmark zara1 --variant dr`.

Many windows are batched per optimizer step (padded agents, masked attention and losses) instead of
the official one-window-at-a-time loop. A checkpoint is written after every epoch to the store's
scratch folder; every epoch reseeds from (seed, epoch), so a run killed mid-epoch and started again
redoes that epoch and ends with the same weights as an uninterrupted run.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Final

import numpy as np
import torch

from fftool.artifacts.schema import CVAE_LOG_FILE, CVAE_MODEL_FILE
from fftool.artifacts.store import Artifact
from fftool.config import CVAEConfig, ForcesConfig, PipelineConfig
from fftool.learning import distributed
from fftool.learning.batches import SceneSet, load_scene_set
from fftool.learning.cvae_model import autocast, build_model, sample
from fftool.learning.features import TRAINING_READS, Prepared, decoder_features, prepare, uses_forces
from fftool.learning.training import (
    epoch_seed,
    fit,
    generator,
    lr_factor,
    make_optimizer,
    optimizer_step,
    save_checkpoint,
)
from fftool.models.forceformer import ForceFormer, LossParts, cvae_loss
from fftool.science.metrics import ade_fde
from fftool.stages.contract import Stage, StageContext

NAME: Final = "cvae"
VERSION: Final = 1
INPUTS: Final = ("windows", "forces")


def epoch_plan(
    train: SceneSet, cfg: CVAEConfig, epoch: int, n_windows: int
) -> tuple[list[np.ndarray], np.random.Generator]:
    """The batches of one epoch (seeded by (seed, epoch)) and the generator that goes on to draw agent caps."""
    rng = np.random.default_rng(epoch_seed(cfg.seed, epoch))
    return train.plan(rng.permutation(train.windows)[:n_windows], cfg.batch_windows, cfg.max_agent_pairs, rng), rng


def training_loss(
    model: ForceFormer,
    prepared: Prepared,
    cfg: CVAEConfig,
    forces_cfg: ForcesConfig | None,
    dt_s: float | None,
    gen: torch.Generator,
) -> LossParts:
    """AgentFormer's loss parts for one batch (posterior reconstruction, KL, best-of-train_k)."""
    with autocast(cfg, prepared.past.device):
        tokens, agent_context = model.encode_past(prepared.past, prepared.agent_mask)
        q = model.posterior(prepared.future, tokens, prepared.agent_mask)
        p = model.prior(agent_context)
        Tf = prepared.future_pos.shape[2]
        recon = model.decode(
            q.sample(gen),
            prepared.past_pos[:, :, -1],
            tokens,
            prepared.agent_mask,
            Tf,
            decoder_features(cfg.variant, prepared, forces_cfg, dt_s),
            last_step=prepared.last_step,
        )
        samples = sample(model, prepared, cfg, forces_cfg, dt_s, cfg.train_k, gen, (tokens, agent_context))
    return cvae_loss(recon, prepared.future_pos, q, p, samples, prepared.agent_mask, cfg.kl_min)


@torch.no_grad()
def val_metrics(
    scenes: SceneSet,
    windows: np.ndarray,
    cfg: CVAEConfig,
    obs_len: int,
    device: torch.device,
    predict: Callable[[Prepared], torch.Tensor],
) -> tuple[float, float]:
    """minADE_K and minFDE_K (metres, minima per agent, independent) of `predict`'s (B, K, A, Tf, 2)
    futures in the normalised frame (rotation-free here: metres as is), ground-truth goals."""
    ade, fde, count = 0.0, 0.0, 0
    for members in scenes.plan(windows, cfg.batch_windows, cfg.max_agent_pairs, np.random.default_rng(0)):
        prepared = prepare(scenes.batch(members).to(device), cfg.variant, obs_len)
        sample_ade, sample_fde = ade_fde(predict(prepared), prepared.future_pos)  # (B, K, A)
        mask = prepared.agent_mask
        ade += float((sample_ade.min(1).values * mask).sum())
        fde += float((sample_fde.min(1).values * mask).sum())
        count += int(mask.sum())
    return ade / max(count, 1), fde / max(count, 1)


def validate(
    model: ForceFormer,
    scenes: SceneSet,
    windows: np.ndarray,
    cfg: CVAEConfig,
    forces_cfg: ForcesConfig | None,
    dt_s: float | None,
    obs_len: int,
    device: torch.device,
) -> tuple[float, float]:
    """The model's validation minADE_K / minFDE_K with K = cfg.k prior samples."""
    model.eval()
    gen = generator(cfg.seed, device)
    return val_metrics(
        scenes,
        windows,
        cfg,
        obs_len,
        device,
        lambda prepared: sample(model, prepared, cfg, forces_cfg, dt_s, cfg.k, gen),
    )


def val_windows(scenes: SceneSet, cfg: CVAEConfig) -> np.ndarray:
    """The fixed validation subset: `val_max_windows` windows drawn with the run's seed (all if 0)."""
    if cfg.val_max_windows and scenes.windows > cfg.val_max_windows:
        return np.sort(np.random.default_rng(cfg.seed).choice(scenes.windows, cfg.val_max_windows, replace=False))
    return np.arange(scenes.windows)


def _rows(index: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """The windows `index` of a batch field."""
    return values[index]


class _Loss(torch.nn.Module):
    """`training_loss` as a module's forward, which DistributedDataParallel wraps (its gradients are averaged
    over the ranks during backward)."""

    def __init__(self, model: ForceFormer, cfg: CVAEConfig, forces_cfg: ForcesConfig | None, dt_s: float | None):
        super().__init__()
        self.model, self.cfg, self.forces_cfg, self.dt_s = model, cfg, forces_cfg, dt_s

    def forward(self, prepared: Prepared, gen: torch.Generator) -> LossParts:
        return training_loss(self.model, prepared, self.cfg, self.forces_cfg, self.dt_s, gen)


@dataclass
class _Trainer:
    """The CVAE-specific half of `training.fit`: an epoch of batched windows under AgentFormer's loss, with
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
    first_steps: list[int] = field(init=False)  # each epoch's first optimizer step; [-1]: the schedule's budget
    loss: torch.nn.Module | None = field(init=False)  # under torchrun: the DDP-wrapped loss; else None

    def __post_init__(self) -> None:
        steps = [len(epoch_plan(self.train, self.cfg, epoch, self.per_epoch)[0]) for epoch in range(self.cfg.epochs)]
        self.first_steps = [0, *itertools.accumulate(steps)]  # the budget is known up front
        self.loss = (
            distributed.wrap(_Loss(self.model, self.cfg, self.forces_cfg, self.dt_s), self.device)
            if distributed.active()
            else None
        )

    def epoch(self, epoch: int, tick: Callable[[int, int], None], previous: dict[str, Any] | None) -> dict[str, Any]:
        """One epoch of the (seed, epoch) plan: throughput (totals carried on from `previous`), the last learning
        rate and the mean loss terms.

        Under torchrun every rank draws the same plan and builds the same global batch (agent caps included),
        then trains on its windows (`distributed.shard`) with its loss scaled so that the averaged gradient is
        the global batch's; rotations and latent samples come from the rank's own generator."""
        cfg, device = self.cfg, self.device
        tic = time.perf_counter()
        gen = generator(distributed.rank_seed(epoch_seed(cfg.seed, epoch)), device)
        plan, rng = epoch_plan(self.train, cfg, epoch, self.per_epoch)
        sums = {"loss": 0.0, "recon": 0.0, "kl": 0.0, "best_of_k": 0.0}
        agents, weight = 0, 1.0  # weight: this rank's share of the global batch's mean loss
        for step, members in enumerate(plan):
            batch = self.train.batch(members, cfg.max_agents, rng)
            agents += int(batch.agent_mask.sum())
            if self.loss is not None:
                mine, share = distributed.shard(members)
                batch, weight = batch.map(partial(_rows, torch.as_tensor(mine))), share / distributed.world_size()
            prepared = prepare(batch.to(device), cfg.variant, self.obs_len, rotate=cfg.rotate, generator=gen)
            if self.loss is None:
                parts = training_loss(self.model, prepared, cfg, self.forces_cfg, self.dt_s, gen)
                total = parts.total
            else:
                parts = self.loss(prepared, gen)
                total = parts.total * share
            factor = lr_factor(
                cfg.schedule,
                self.first_steps[epoch] + step,
                self.first_steps[-1],
                cfg.warmup_fraction,
                epoch,
                cfg.decay_every,
                cfg.decay_gamma,
            )
            optimizer_step(self.model, self.optimizer, total, cfg.lr * factor, cfg.grad_clip)
            for name, value in zip(sums, parts):
                sums[name] += value.item() * weight / len(plan)
            tick(step + 1, len(plan))
        sums = distributed.sum_over_ranks(sums, device)
        train_s = time.perf_counter() - tic
        seen = previous or {"agent_windows_seen": 0, "train_seconds": 0.0}
        return {
            "train_seconds": round(float(seen["train_seconds"]) + train_s, 3),
            "agent_windows_seen": int(seen["agent_windows_seen"]) + agents,
            "agent_windows_per_s": round(agents / train_s, 2),
            "lr": self.optimizer.param_groups[0]["lr"],
            **{f"train_{name}": value for name, value in sums.items()},
        }

    def validate(self) -> dict[str, float]:
        """minADE_K and minFDE_K of the fixed validation subset."""
        cfg = self.cfg
        ade, fde = validate(
            self.model, self.val, self.val_subset, cfg, self.forces_cfg, self.dt_s, self.obs_len, self.device
        )
        return {f"val_min_ade@{cfg.k}_m": ade, f"val_min_fde@{cfg.k}_m": fde}


def _trainer(
    cfg: CVAEConfig,
    forces_cfg: ForcesConfig,
    benchmark: str,
    windows: Artifact,
    forces: Artifact | None,
    device: torch.device,
) -> _Trainer:
    """The benchmark's scenes with the forces the variant reads, and a fresh model seeded by the run's seed."""
    reads = TRAINING_READS[cfg.variant]
    train = load_scene_set(windows, forces, benchmark, "train", cfg.train_stride, reads)
    val = load_scene_set(windows, forces, benchmark, "val", reads=reads)
    val_subset = val_windows(val, cfg)
    torch.manual_seed(cfg.seed)
    model = build_model(cfg).to(device)
    return _Trainer(
        cfg=cfg,
        forces_cfg=forces_cfg if forces is not None else None,
        model=model,
        optimizer=make_optimizer(model, cfg.optimizer, cfg.lr, cfg.weight_decay),
        train=train,
        val=val,
        val_subset=val_subset,
        obs_len=int(windows.manifest.stats["obs_len"]),
        dt_s=float(forces.manifest.stats["dt_s"]) if forces is not None else None,  # the forces' time step
        per_epoch=min(train.windows, cfg.max_train_windows) if cfg.max_train_windows else train.windows,
        device=device,
    )


def train(
    cfg: CVAEConfig, forces_cfg: ForcesConfig, windows: Artifact, forces: Artifact | None, ctx: StageContext
) -> dict[str, Any]:
    """Train with validation every epoch; write the best model and the log; return the manifest stats.

    cfg: the `cvae` section (variant included); forces_cfg: the force constants used in the decoder;
    windows, forces: input artifacts (no forces for the baseline and goal variants); ctx: the benchmark,
    build and scratch folders, device, callbacks.
    """
    benchmark, device, out_dir = ctx.need_benchmark(), distributed.device(ctx.device()), ctx.out_dir
    trainer = _trainer(cfg, forces_cfg, benchmark, windows, forces, device)
    started = time.perf_counter()
    progress = fit(
        trainer, ctx, epochs=cfg.epochs, seed=cfg.seed, best_by=f"val_min_ade@{cfg.k}_m", log_name=CVAE_LOG_FILE
    )
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
    return {
        "benchmark": benchmark,
        "variant": cfg.variant,
        "device": str(device),
        "torch_threads": torch.get_num_threads(),  # results depend on it (float summation order)
        "world_size": distributed.world_size(),  # torchrun ranks (docs/scaling.md); results depend on it too
        "backend": distributed.backend(),
        "train_windows": trainer.train.windows,
        "train_windows_per_epoch": trainer.per_epoch,
        "val_windows": len(trainer.val_subset),
        "best_epoch": progress.best_epoch,
        f"best_val_min_ade@{cfg.k}_m": progress.best_metric,
        "resumed_from_epoch": progress.start_epoch,
        "seconds_this_run": time.perf_counter() - started,
        "parameters": sum(p.numel() for p in trainer.model.parameters()),
        "log": progress.log,
    }


def build(cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: StageContext) -> dict[str, Any]:
    """The stage contract: train one benchmark's CVAE of the configured variant."""
    return train(cfg.cvae, cfg.forces, inputs["windows"], inputs.get("forces"), ctx)


def reads(cfg: PipelineConfig) -> tuple[str, ...]:
    """Upstream stages: the forces artifact only for the variants whose inputs include a force."""
    return INPUTS if uses_forces(cfg.cvae.variant) else ("windows",)


STAGE = Stage(
    NAME,
    VERSION,
    INPUTS,
    command="fftool train-cvae",
    section=lambda cfg: cfg.cvae,
    build=build,
    description=lambda cfg, benchmark: f"train CVAE {cfg.cvae.variant} ({benchmark})",
    per_benchmark=True,
    distributed=True,
    needs=reads,
    reads=lambda cfg: {"forces": TRAINING_READS[cfg.cvae.variant]},
    command_args=lambda cfg: f" --variant {cfg.cvae.variant}",
)
