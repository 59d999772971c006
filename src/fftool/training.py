"""Plain helpers shared by the training stages: seeding, devices, resumable checkpoints, CSV logs."""

from __future__ import annotations

import csv
import math
import os
import random
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.tensorboard import SummaryWriter

from fftool.schema import TENSORBOARD_DIR


def seed_all(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def generator(seed: int, device: torch.device) -> torch.Generator:
    """A torch generator on `device`, so sampling is reproducible on CPU and CUDA alike."""
    gen = torch.Generator(device=device)
    gen.manual_seed(seed)
    return gen


def make_optimizer(model: torch.nn.Module, name: str, lr: float, weight_decay: float) -> torch.optim.Optimizer:
    """Adam (the papers' choice) or AdamW with decoupled weight decay; schedules then set the rate per step."""
    if name == "adamw":
        return torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=weight_decay)
    return torch.optim.Adam(model.parameters(), lr=lr)


def set_lr(optimizer: torch.optim.Optimizer, lr: float) -> None:
    for group in optimizer.param_groups:
        group["lr"] = lr


def lr_factor(
    schedule: str,
    step: int,
    total_steps: int,
    warmup_fraction: float,
    epoch: int = 0,
    decay_every: int = 1,
    decay_gamma: float = 1.0,
) -> float:
    """The learning-rate multiplier for optimizer step `step` (0-based) of a `total_steps` budget.

    A linear warm-up over the first round(warmup_fraction · total_steps) steps, then: constant (1);
    step (decay_gamma ** (epoch // decay_every), torch's StepLR stepped once per epoch); or cosine (half
    a cosine from 1 to 0 over the remaining steps). A function of the step count alone, so a run's
    schedule never depends on how fast the machine is.
    """
    warmup = round(warmup_fraction * total_steps)
    if step < warmup:
        return (step + 1) / warmup
    if schedule == "step":
        return decay_gamma ** (epoch // decay_every)
    if schedule == "constant":
        return 1.0
    return 0.5 * (1 + math.cos(math.pi * min(1.0, (step - warmup) / max(1, total_steps - warmup))))


def save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    """Write atomically: a killed process never leaves a truncated checkpoint."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial")
    torch.save(state, partial)
    os.replace(partial, path)


def load_checkpoint(path: Path, device: torch.device) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    return torch.load(path, map_location=device, weights_only=True)


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    if not rows:
        return
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


@dataclass
class Progress:
    """What a resumable training carries from epoch to epoch: its log and the best weights so far."""

    start_epoch: int = 0
    log: list[dict[str, Any]] = field(default_factory=list)
    best_metric: float = float("inf")
    best_epoch: int = -1
    best_state: dict[str, Any] | None = None

    def record(self, row: dict[str, Any], metric: float, model: torch.nn.Module) -> None:
        """Log an epoch; keep a copy of the weights when `metric` (lower is better) improves."""
        self.log.append(row)
        if metric < self.best_metric:
            self.best_metric, self.best_epoch = metric, int(row["epoch"])
            self.best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}


def resume(path: Path, device: torch.device, stateful: dict[str, Any]) -> Progress:
    """Restore model/optimizer/scheduler states from the last epoch checkpoint, if there is one."""
    state = load_checkpoint(path, device)
    if state is None:
        return Progress()
    for name, obj in stateful.items():
        obj.load_state_dict(state["states"][name])
    best = state["best"]
    return Progress(state["epoch"] + 1, state["log"], best["metric"], best["epoch"], best["state"])


def save_progress(path: Path, progress: Progress, epoch: int, stateful: dict[str, Any]) -> None:
    """The end-of-epoch checkpoint `resume` reads (epoch is 0-based)."""
    best = {"metric": progress.best_metric, "epoch": progress.best_epoch, "state": progress.best_state}
    states = {name: obj.state_dict() for name, obj in stateful.items()}
    save_checkpoint(path, {"states": states, "epoch": epoch, "log": progress.log, "best": best})


class Curves:
    """Per-epoch log rows as TensorBoard scalars: written live to the scratch folder while training (so
    `tensorboard --logdir <root>` follows a run), copied into the artifact when it is done."""

    def __init__(self, scratch: Path, start_epoch: int) -> None:
        self.folder = scratch / TENSORBOARD_DIR
        self.writer = SummaryWriter(self.folder, purge_step=start_epoch + 1)  # drops a killed run's extra rows

    def add(self, row: dict[str, Any]) -> None:
        for name, value in row.items():
            if name != "epoch":
                self.writer.add_scalar(name, value, int(row["epoch"]))
        self.writer.flush()

    def finish(self, out_dir: Path) -> None:
        self.writer.close()
        shutil.copytree(self.folder, out_dir / TENSORBOARD_DIR)
