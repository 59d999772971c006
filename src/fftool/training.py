"""Plain helpers shared by the training stages: seeding, devices, resumable checkpoints, CSV logs."""

from __future__ import annotations

import csv
import math
import os
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch


def seed_all(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def generator(seed: int, device: torch.device) -> torch.Generator:
    """A torch generator on `device`, so sampling is reproducible on CPU and CUDA alike."""
    gen = torch.Generator(device=device)
    gen.manual_seed(seed)
    return gen


def lr_factor(
    schedule: str, progress: float, epochs: int, warmup_fraction: float, decay_every: int, decay_gamma: float
) -> float:
    """The learning-rate multiplier after `progress` epochs (fractional) of an `epochs`-epoch budget.

    step: decay_gamma ** (finished epochs // decay_every), as torch's StepLR stepped once per epoch.
    cosine: linear warm-up over the first warmup_fraction of the budget, then half a cosine to 0. Defined
    by the step count alone, so a run's schedule never depends on how fast the machine is.
    """
    if schedule == "step":
        return decay_gamma ** (int(progress) // decay_every)
    t = progress / epochs
    if t < warmup_fraction:
        return t / warmup_fraction
    return 0.5 * (1 + math.cos(math.pi * (t - warmup_fraction) / (1 - warmup_fraction)))


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
