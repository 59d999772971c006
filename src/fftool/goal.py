"""Train the U-Net goal estimator of one leave-one-out benchmark.

Reads: windows (train and val parts of the benchmark) and maps. Writes: `goal/<fp>/model.pt` (best
weights by validation goal-FDE@K, with the resolved config), `log.csv` (every loss term per epoch) and
the same curves as TensorBoard events in `tensorboard/`.
Run: `fftool train-goal --benchmark zara1`. Checkpoints go to the store's scratch folder every epoch, so
an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final

import numpy as np
import torch

from fftool.batches import load_agent_windows, load_scene_maps
from fftool.config import GoalConfig, GoalsConfig
from fftool.goalnet import build_model, evaluate, goal_inputs, goal_loss, input_channels
from fftool.heatmaps import world_to_cells
from fftool.schema import GOAL_LOG_FILE, GOAL_MODEL_FILE
from fftool.store import Artifact
from fftool.training import (
    Curves,
    generator,
    lr_factor,
    make_optimizer,
    resume,
    save_checkpoint,
    save_progress,
    seed_all,
    set_lr,
    write_csv,
)

NAME: Final = "goal"
VERSION: Final = 1
INPUTS: Final = ("windows", "maps")


def build(
    cfg: GoalConfig,
    goals_cfg: GoalsConfig,
    benchmark: str,
    windows: Artifact,
    maps: Artifact,
    out_dir: Path,
    scratch: Path,
    device: torch.device,
    on_progress: Callable[[str, int, int], None] | None = None,
    on_epoch: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Train, validating every epoch; write the best model and the log. Returns the manifest stats.

    Args:
        cfg: the `goal` section. goals_cfg: the sampling used for validation goal-FDE@K.
        benchmark: the leave-one-out benchmark whose train part is used.
        windows, maps: input artifacts. out_dir: the build folder.
        scratch: where the resumable checkpoint lives (kept if this build fails).
        device: torch device. on_progress: called with (phase, done, total) after every batch.
        on_epoch: called with each epoch's log row (a line per epoch even where no live bar shows).
    """
    seed_all(cfg.seed)
    obs_len = int(windows.manifest.stats["obs_len"])
    pred_len = int(windows.manifest.stats["pred_len"])
    train = load_agent_windows(windows, benchmark, "train", stride=cfg.train_stride)
    val = load_agent_windows(windows, benchmark, "val")
    if cfg.val_max and len(val) > cfg.val_max:
        keep = np.sort(np.random.default_rng(cfg.seed).choice(len(val), cfg.val_max, replace=False))
        val = val.subset(keep)
    scene_maps = load_scene_maps(maps).to(device)
    train_scene, val_scene = scene_maps.index_of_sources(train.source), scene_maps.index_of_sources(val.source)
    train_xy = torch.as_tensor(train.xy, dtype=torch.float32)

    in_channels = input_channels(cfg, obs_len, scene_maps.channels)
    model = build_model(cfg, in_channels).to(device)
    n_train = min(len(train), cfg.max_train) if cfg.max_train else len(train)
    batches = -(-n_train // cfg.batch_size)
    optimizer = make_optimizer(model, cfg.optimizer, cfg.lr, cfg.weight_decay)
    stateful = {"model": model, "optimizer": optimizer}
    progress = resume(scratch / "last.pt", device, stateful)
    curves = Curves(scratch, progress.start_epoch)

    started = time.perf_counter()
    for epoch in range(progress.start_epoch, cfg.epochs):
        model.train()
        tic = time.perf_counter()
        gen = generator(cfg.seed * 100_003 + epoch, torch.device("cpu"))
        order = torch.randperm(len(train), generator=gen)[:n_train]
        sums = {"loss": 0.0, "bce": 0.0, "mse": 0.0}
        for b in range(batches):
            index = order[b * cfg.batch_size : (b + 1) * cfg.batch_size]
            xy = train_xy[index].to(device)
            angle = torch.rand(len(index), generator=gen, dtype=torch.float32) * 2 * torch.pi
            mirror = torch.rand(len(index), generator=gen, dtype=torch.float32) < 0.5
            if not cfg.augment or cfg.align_heading:
                angle = torch.zeros_like(angle)
            if not cfg.augment:
                mirror = torch.zeros_like(mirror)
            x, center, R = goal_inputs(
                xy[:, :obs_len],
                train_scene[index].to(device),
                scene_maps,
                cfg,
                angle.to(device),
                mirror.to(device),
                pred_len,
            )
            goal_cells = world_to_cells(xy[:, -1:], center, R, cfg.resolution_m, cfg.crop_cells)[:, 0]
            loss, bce, mse = goal_loss(model(x), goal_cells, cfg)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
            set_lr(
                optimizer,
                cfg.lr * lr_factor(cfg.schedule, epoch * batches + b, cfg.epochs * batches, cfg.warmup_fraction),
            )
            optimizer.step()
            for name, value in (("loss", loss), ("bce", bce), ("mse", mse)):
                sums[name] += value.item() / batches
            if on_progress:
                on_progress(f"epoch {epoch + 1}/{cfg.epochs}", b + 1, batches)
        fde_k, fde_1 = evaluate(model, val, val_scene, scene_maps, cfg, goals_cfg, device, cfg.seed, obs_len, pred_len)
        row = {
            "epoch": epoch + 1,
            "seconds": round(time.perf_counter() - tic, 3),
            "train_loss": sums["loss"],
            "train_bce": sums["bce"],
            "train_mse_cells2": sums["mse"],
            f"val_goal_fde@{goals_cfg.k}_m": fde_k,
            "val_goal_fde@1_m": fde_1,
        }
        progress.record(row, fde_k, model)
        curves.add(row)
        if on_epoch:
            on_epoch(row)
        save_progress(scratch / "last.pt", progress, epoch, stateful)
    curves.finish(out_dir)

    save_checkpoint(
        out_dir / GOAL_MODEL_FILE,
        {
            "state_dict": progress.best_state,
            "in_channels": in_channels,
            "config": cfg.model_dump(mode="json"),
            "benchmark": benchmark,
            "best_epoch": progress.best_epoch,
        },
    )
    write_csv(out_dir / GOAL_LOG_FILE, progress.log)
    return {
        "benchmark": benchmark,
        "device": str(device),
        "torch_threads": torch.get_num_threads(),  # results depend on it (float summation order)
        "train_agent_windows": len(train),
        "train_per_epoch": n_train,
        "val_agent_windows": len(val),
        "best_epoch": progress.best_epoch,
        f"best_val_goal_fde@{goals_cfg.k}_m": progress.best_metric,
        "epochs": cfg.epochs,
        "resumed_from_epoch": progress.start_epoch,
        "seconds_this_run": time.perf_counter() - started,
        "log": progress.log,
    }
