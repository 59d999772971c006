"""Train the U-Net goal estimator of one leave-one-out benchmark.

Reads: windows (train and val parts of the benchmark) and maps. Writes: `goal/<fp>/model.pt` (best
weights by validation goal-FDE@K, with the resolved config), `log.csv` (every loss term per epoch) and
the same curves as TensorBoard events in `tensorboard/`.
Run: `fftool train-goal --benchmarks zara1`. Checkpoints go to the store's scratch folder every epoch, so
an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, Final

import torch

from fftool.artifacts.schema import COMMANDS, GOAL_LOG_FILE, GOAL_MODEL_FILE, VERSIONS
from fftool.artifacts.store import Artifact
from fftool.config import GoalConfig, GoalsConfig, PipelineConfig
from fftool.errors import UsageError
from fftool.learning import distributed
from fftool.learning.batches import AgentWindows, SceneMaps, load_agent_windows
from fftool.learning.goal_model import (
    Neighbours,
    build_model,
    evaluate,
    goal_inputs,
    goal_loss,
    input_channels,
    speed_scaled,
    supervised_steps,
)
from fftool.learning.scene_prior import goal_scene_index, load_goal_scenes
from fftool.learning.training import (
    Schedule,
    Step,
    epoch_seed,
    fit,
    generator,
    make_optimizer,
    save_checkpoint,
    seed_all,
    validation_subset,
)
from fftool.models import GoalUNet
from fftool.science.heatmaps import world_to_cells
from fftool.stages.contract import Reads, Stage, StageContext

NAME: Final = "goal"
# Validation picks the best epoch by goal-FDE@K of goals drawn as `sample-goals` draws them: these settings
# of the goals section steer which weights are kept, so they are part of the goal model's fingerprint.
VALIDATION_SAMPLING: Final = tuple(
    f"goals.{key}"
    for key in ("k", "method", "temperature", "threshold", "samples", "kmeans_iterations", "mode_radius_cells")
)


@dataclass
class _Trainer:
    """The goal U-Net's part of `training.fit`: the steps of an epoch of augmented crops under the BCE+MSE
    heatmap loss, and the validation goal-FDE@K that picks the best epoch."""

    cfg: GoalConfig
    goals_cfg: GoalsConfig
    model: GoalUNet
    optimizer: torch.optim.Optimizer
    train_xy: torch.Tensor  # (N, T, 2) on the CPU
    train_scene: torch.Tensor  # each training window's index into `maps`
    val: AgentWindows
    val_scene: torch.Tensor
    train_neighbours: Neighbours | None  # with goal.neighbour_channels: the other walkers of each window
    val_neighbours: Neighbours | None
    maps: SceneMaps
    obs_len: int
    pred_len: int
    per_epoch: int  # training windows per epoch
    device: torch.device
    terms: tuple[str, ...] = ("loss", "bce", "mse")
    schedule: Schedule = field(init=False)
    net: torch.nn.Module = field(init=False)  # the model, in DistributedDataParallel under torchrun
    future_index: list[int] = field(init=False)  # the window rows of the supervised future steps

    def __post_init__(self) -> None:
        cfg = self.cfg
        self.schedule = Schedule(cfg.lr, cfg.schedule, (self._batches,) * cfg.epochs, cfg.warmup_fraction)
        self.net = distributed.wrap(self.model, self.device)
        self.future_index = [self.obs_len + step - 1 for step in supervised_steps(cfg, self.pred_len)]

    @property
    def _batches(self) -> int:
        return -(-self.per_epoch // self.cfg.batch_size)

    @property
    def grad_clip(self) -> float:
        return self.cfg.grad_clip

    def _epoch_windows(self, gen: torch.Generator) -> torch.Tensor:
        """The training windows of an epoch: `per_epoch` of them in a random order, each at most once."""
        return torch.randperm(len(self.train_xy), generator=gen)[: self.per_epoch]

    def steps(self, epoch: int) -> tuple[int, Iterator[Step]]:
        """`per_epoch` windows drawn by (seed, epoch).

        Under torchrun every rank draws the same order and augmentations for the global batch and trains on its
        windows (`distributed.shard`), its loss scaled so that the averaged gradient is the global batch's."""
        cfg, device, batches = self.cfg, self.device, self._batches
        gen = generator(epoch_seed(cfg.seed, epoch), torch.device("cpu"))
        order = self._epoch_windows(gen)

        def each() -> Iterator[Step]:
            for b in range(batches):
                index = order[b * cfg.batch_size : (b + 1) * cfg.batch_size]
                angle = torch.rand(len(index), generator=gen, dtype=torch.float32) * 2 * torch.pi
                mirror = torch.rand(len(index), generator=gen, dtype=torch.float32) < 0.5
                reverse = torch.rand(len(index), generator=gen, dtype=torch.float32) < cfg.time_reversal
                # Drawn only when asked for, so a recipe without map dropout keeps its augmentations' draws.
                blank = torch.zeros(len(index), dtype=torch.bool)
                if cfg.map_dropout:
                    blank = torch.rand(len(index), generator=gen, dtype=torch.float32) < cfg.map_dropout
                scale = torch.ones(len(index))  # drawn only when asked for, as the map dropout
                if cfg.speed_scale != 1:
                    log_range = math.log(cfg.speed_scale)
                    scale = torch.exp((2 * torch.rand(len(index), generator=gen) - 1) * log_range)
                share = 1.0  # this rank's factor on its mean loss
                if distributed.active():
                    mine, share = distributed.shard(index.numpy())
                    keep = torch.as_tensor(mine)
                    index, angle, mirror, reverse, blank, scale = (
                        index[keep], angle[keep], mirror[keep], reverse[keep], blank[keep], scale[keep]
                    )  # fmt: skip
                xy = self.train_xy[index]
                xy = torch.where(reverse[:, None, None], xy.flip(1), xy)
                if cfg.speed_scale != 1:  # off, the windows stay bit for bit as the recipe's models saw them
                    xy = speed_scaled(xy, scale, self.obs_len)
                xy = xy.to(device)
                if not cfg.augment or cfg.align_heading:
                    angle = torch.zeros_like(angle)
                if not cfg.augment:
                    mirror = torch.zeros_like(mirror)
                scene = torch.where(blank, len(self.maps.names), self.train_scene[index]).to(device)
                past, others = xy[:, : self.obs_len], None
                if self.train_neighbours is not None:  # played backwards with the crop's own path
                    others = self.train_neighbours.observed(index, self.obs_len, reverse).to(device)
                x, center, R = goal_inputs(
                    past, scene, self.maps, cfg, angle.to(device), mirror.to(device), self.pred_len, others
                )  # fmt: skip
                future = xy[:, self.future_index]  # (b, supervised steps, 2), the goal last
                terms = goal_loss(self.net(x), world_to_cells(future, center, R, cfg.resolution_m, cfg.crop_cells), cfg)
                if distributed.active():
                    yield Step(terms[0] * share, tuple(terms), share / distributed.world_size())
                else:
                    yield Step(terms[0], tuple(terms))

        return batches, each()

    def columns(
        self, epoch: int, sums: dict[str, float], seen: int, seconds: float, previous: dict[str, Any] | None
    ) -> dict[str, Any]:
        """The mean loss terms (none adds up over epochs)."""
        return {"train_loss": sums["loss"], "train_bce": sums["bce"], "train_mse_cells2": sums["mse"]}

    def validate(self) -> dict[str, float]:
        """Goal-FDE@K and FDE@1 of the validation windows, with the run's fixed sampling seed."""
        cfg, k = self.cfg, self.goals_cfg.k
        fde_k, fde_1 = evaluate(
            self.model,
            self.val,
            self.val_scene,
            self.maps,
            cfg,
            self.goals_cfg,
            self.device,
            cfg.seed,
            self.obs_len,
            self.pred_len,
            self.val_neighbours,
        )
        return {f"val_goal_fde@{k}_m": fde_k, "val_goal_fde@1_m": fde_1}


def _trainer(
    cfg: GoalConfig, goals_cfg: GoalsConfig, benchmark: str, windows: Artifact, maps: Artifact, device: torch.device
) -> _Trainer:
    """The benchmark's windows and maps, and a fresh model seeded by the run's seed."""
    seed_all(cfg.seed)
    obs_len = int(windows.manifest.stats["obs_len"])
    pred_len = int(windows.manifest.stats["pred_len"])
    if cfg.supervised_steps > pred_len:
        raise UsageError(
            f"goal.supervised_steps: expected at most the {pred_len} predicted steps, got {cfg.supervised_steps}"
        )
    train = load_agent_windows(windows, benchmark, "train", stride=cfg.train_stride)
    val = load_agent_windows(windows, benchmark, "val")
    # each window's other walkers, found before the validation subset so that they all stay in view
    train_neighbours = Neighbours.of(train.xy, train.window_id) if cfg.neighbour_channels else None
    val_neighbours = Neighbours.of(val.xy, val.window_id) if cfg.neighbour_channels else None
    if cfg.val_max and len(val) > cfg.val_max:
        chosen = validation_subset(len(val), cfg.val_max, cfg.seed)
        val = val.subset(chosen)
        val_neighbours = None if val_neighbours is None else val_neighbours.subset(chosen)
    scene_maps = load_goal_scenes(maps, windows, benchmark, cfg).to(device)
    # Channels-last weights make every convolution run channels-last: on a CPU its training step is about 1.5×
    # as fast for this thin U-Net (benchmarks/bench_goal_step.py). The saved weights load into any layout.
    model = build_model(cfg, input_channels(cfg, obs_len, scene_maps.channels)).to(
        device, memory_format=torch.channels_last
    )
    optimizer = make_optimizer(model, cfg.optimizer, cfg.lr, cfg.weight_decay)
    return _Trainer(
        cfg=cfg,
        goals_cfg=goals_cfg,
        model=model,
        optimizer=optimizer,
        train_xy=torch.as_tensor(train.xy, dtype=torch.float32),
        train_scene=goal_scene_index(scene_maps, train, cfg, cross_fit=True),
        val=val,
        val_scene=goal_scene_index(scene_maps, val, cfg, cross_fit=False),
        train_neighbours=train_neighbours,
        val_neighbours=val_neighbours,
        maps=scene_maps,
        obs_len=obs_len,
        pred_len=pred_len,
        per_epoch=min(len(train), cfg.max_train) if cfg.max_train else len(train),
        device=device,
    )


def train(
    cfg: GoalConfig, goals_cfg: GoalsConfig, windows: Artifact, maps: Artifact, ctx: StageContext
) -> dict[str, Any]:
    """Train, validating every epoch; write the best model and the log. Returns the manifest stats.

    cfg: the `goal` section; goals_cfg: the sampling used for validation goal-FDE@K; windows, maps: input
    artifacts; ctx: the benchmark (its train part is used), build and scratch folders, device, callbacks.
    """
    benchmark, device, out_dir = ctx.need_benchmark(), distributed.device(ctx.device()), ctx.dir
    trainer = _trainer(cfg, goals_cfg, benchmark, windows, maps, device)
    started, best_by = time.perf_counter(), f"val_goal_fde@{goals_cfg.k}_m"
    progress = fit(trainer, ctx, seed=cfg.seed, best_by=best_by, log_name=GOAL_LOG_FILE)
    save_checkpoint(
        out_dir / GOAL_MODEL_FILE,
        {
            "state_dict": progress.best_state,
            "in_channels": input_channels(cfg, trainer.obs_len, trainer.maps.channels),
            "config": cfg.model_dump(mode="json"),
            "sampling": goals_cfg.model_dump(mode="json"),
            "benchmark": benchmark,
            "best_epoch": progress.best_epoch,
        },
    )
    return progress.stats(benchmark, device, best_by, time.perf_counter() - started) | {
        "train_agent_windows": len(trainer.train_xy),
        "train_per_epoch": trainer.per_epoch,
        "val_agent_windows": len(trainer.val),
        "epochs": cfg.epochs,
    }


def build(cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: StageContext) -> dict[str, Any]:
    """The stage contract: train one benchmark's goal U-Net."""
    return train(cfg.goal, cfg.goals, inputs["windows"], inputs["maps"], ctx)


STAGE = Stage(
    NAME,
    VERSIONS[NAME],
    COMMANDS[NAME],
    label="train goal U-Net",
    declare=lambda cfg: Reads(params=("goal.*", *VALIDATION_SAMPLING), artifacts={"windows": None, "maps": None}),
    build=build,
    section="goal",
    per_benchmark=True,
    distributed=True,
)
