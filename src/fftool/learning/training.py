"""What the training stages share: the resumable epoch loop (`fit`), seeding, optimizer steps and learning-rate
schedules, checkpoints, model files, CSV and TensorBoard logs."""

from __future__ import annotations

import copy
import csv
import io
import math
import os
import random
import shutil
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np
import torch
from torch.utils.tensorboard import SummaryWriter

from fftool.artifacts.schema import TENSORBOARD_DIR
from fftool.errors import IntegrityError
from fftool.learning import distributed
from fftool.learning.batches import SceneSet
from fftool.outputs import replacing_file
from fftool.ui import warn

# What loading a readable checkpoint into objects it does not fit raises (missing or extra keys, other
# shapes, other types); ValueError includes pydantic's ValidationError of a saved config.
_UNFIT = (KeyError, TypeError, ValueError, RuntimeError, IndexError, AttributeError)


def seed_all(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def validation_subset(n: int, most: int, seed: int) -> np.ndarray:
    """The fixed validation subset of a run: `most` of `n` items drawn with the run's seed, sorted (all if 0)."""
    if most and n > most:
        return np.sort(np.random.default_rng(seed).choice(n, most, replace=False))
    return np.arange(n)


def epoch_batches(
    scenes: SceneSet,
    seed: int,
    epoch: int,
    n_windows: int,
    batch_windows: int,
    max_pairs: int,
    max_agents: int = 0,
) -> tuple[list[np.ndarray], np.random.Generator]:
    """The batches of epoch `epoch` of a run seeded `seed` (`n_windows` random windows), and the generator
    that goes on to draw agent caps; a function of (seed, epoch) alone, so a resumed run draws the same."""
    rng = np.random.default_rng(epoch_seed(seed, epoch))
    order = rng.permutation(scenes.windows)[:n_windows]
    return scenes.plan(order, batch_windows, max_pairs, rng, max_agents), rng


def epoch_seed(seed: int, epoch: int) -> int:
    """The seed of epoch `epoch` (0-based) of a run seeded `seed`. Every epoch draws from its own seed, so
    a run resumed after its last finished epoch draws exactly what the uninterrupted run drew."""
    return seed * 100_003 + epoch


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


def optimizer_step(
    model: torch.nn.Module, optimizer: torch.optim.Optimizer, loss: torch.Tensor, lr: float, grad_clip: float
) -> None:
    """One update at rate `lr` with the gradients of `loss`, their global norm clipped to `grad_clip` (0: not)."""
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if grad_clip:
        torch.nn.utils.clip_grad_norm_(model.parameters(), grad_clip)
    set_lr(optimizer, lr)
    optimizer.step()


def lr_factor(
    schedule: str,
    step: int,
    total_steps: int,
    warmup_fraction: float,
    epoch: int = 0,
    decay_every: int = 1,
    decay_gamma: float = 1.0,
    epochs: int = 1,
    fix_epochs: int = 0,
) -> float:
    """The learning-rate multiplier for optimizer step `step` (0-based) of a `total_steps` budget.

    A linear warm-up over the first round(warmup_fraction · total_steps) steps, then: constant (1);
    step (decay_gamma ** (epoch // decay_every), torch's StepLR stepped once per epoch); linear (1 for
    `fix_epochs` epochs, then 1 - (epoch - fix_epochs) / (epochs - fix_epochs + 1): AgentFormer's LambdaLR);
    or cosine (half a cosine from 1 to 0 over the remaining steps). A function of the step count alone, so
    a run's schedule never depends on how fast the machine is.
    """
    warmup = round(warmup_fraction * total_steps)
    if step < warmup:
        return (step + 1) / warmup
    if schedule == "step":
        return decay_gamma ** (epoch // decay_every)
    if schedule == "linear":
        return 1.0 - max(0, epoch - fix_epochs) / float(epochs - fix_epochs + 1)
    if schedule == "constant":
        return 1.0
    return 0.5 * (1 + math.cos(math.pi * min(1.0, (step - warmup) / max(1, total_steps - warmup))))


@dataclass(frozen=True)
class Schedule:
    """The run's epochs (the optimizer steps of each, known up front) and the learning rate of every step:
    `lr` times `lr_factor` of the step's place in the budget."""

    lr: float
    kind: str
    steps_per_epoch: tuple[int, ...]
    warmup_fraction: float = 0.0
    decay_every: int = 1
    decay_gamma: float = 1.0
    fix_epochs: int = 0

    @property
    def epochs(self) -> int:
        return len(self.steps_per_epoch)

    def at(self, epoch: int, step: int) -> float:
        """The rate of step `step` (0-based) of epoch `epoch`."""
        factor = lr_factor(
            self.kind,
            sum(self.steps_per_epoch[:epoch]) + step,
            sum(self.steps_per_epoch),
            self.warmup_fraction,
            epoch,
            self.decay_every,
            self.decay_gamma,
            self.epochs,
            self.fix_epochs,
        )
        return self.lr * factor


def save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    """Write atomically (`outputs.replacing_file`): a killed process never leaves a truncated checkpoint, and
    two processes never write into or rename each other's temporary file. Serialised in memory first: torch
    names the archive inside the file after the path it writes, so the temporary's random name would make the
    same weights two different files."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    with replacing_file(path) as unfinished:
        unfinished.write_bytes(buffer.getvalue())


def _load(path: Path, device: torch.device) -> dict[str, Any] | None:
    """The checkpoint's contents, or None when its bytes do not load (truncated, overwritten, not torch's)."""
    try:
        return torch.load(path, map_location=device, weights_only=True)
    except OSError:
        raise  # the disk's or the permissions' fault, not the file's
    except Exception:  # what torch raises depends on where the bytes are damaged
        return None


def _summary(exc: Exception) -> str:
    """An error on one line of at most 200 characters, for a message that names its cause."""
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    return text if len(text) <= 200 else text[:199] + "…"


@contextmanager
def model_file(path: Path, device: torch.device, command: str) -> Iterator[dict[str, Any]]:
    """An artifact's model file, for the `with` body to rebuild its model from.

    A file that does not load as plain tensors and values, or whose contents do not fit what the body
    builds, is an IntegrityError naming the file and `command`, the one that rebuilds it. torch's own
    message is left out on purpose: it suggests `weights_only=False`, which would run a tampered pickle.
    """
    saved = _load(path, device)
    if saved is None:
        problem = "damaged or modified: it does not load as tensors and plain values"
    else:
        try:
            yield saved
            return
        except _UNFIT as exc:
            problem = f"its contents do not fit the model ({_summary(exc)})"
    raise IntegrityError(f"{path}: not a valid fftool checkpoint, {problem}; rebuild it with `{command}`")


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

    def stats(self, benchmark: str, device: torch.device, best_by: str, seconds: float) -> dict[str, Any]:
        """The manifest stats every trained model shares: where and how it ran, its best epoch and the log."""
        return {
            "benchmark": benchmark,
            "device": str(device),
            "torch_threads": torch.get_num_threads(),  # results depend on it (float summation order)
            "world_size": distributed.world_size(),  # torchrun ranks (docs/scaling.md); results depend on it too
            "backend": distributed.backend(),
            "best_epoch": self.best_epoch,
            f"best_{best_by}": self.best_metric,
            "resumed_from_epoch": self.start_epoch,
            "seconds_this_run": seconds,
            "log": self.log,
        }


def resume(path: Path, device: torch.device, stateful: dict[str, Any]) -> Progress:
    """Restore model/optimizer states and the progress from the last epoch checkpoint, if there is one.

    A checkpoint that does not load or does not fit `stateful` (whose "model" is the module the best
    weights belong to) must not block every later run: it is renamed aside with a warning, the objects
    get their states back and training starts over.
    """
    if not path.is_file():
        return Progress()
    state = _load(path, device)
    if state is None:
        return _set_aside(path, "it does not load (truncated or overwritten)")
    fresh = {name: copy.deepcopy(obj.state_dict()) for name, obj in stateful.items()}
    try:
        return _restore(state, stateful)
    except _UNFIT as exc:
        for name, obj in stateful.items():
            obj.load_state_dict(fresh[name])
        return _set_aside(path, f"it does not fit the model or optimizer ({_summary(exc)})")


def _restore(state: dict[str, Any], stateful: dict[str, Any]) -> Progress:
    """Load `state` into the objects, checking the shapes that loading alone does not: optimizer moments
    (else the first step fails) and the best weights (else the final model file does not load)."""
    for name, obj in stateful.items():
        obj.load_state_dict(state["states"][name])
        if isinstance(obj, torch.optim.Optimizer):
            for param in (p for group in obj.param_groups for p in group["params"]):
                for key, value in obj.state.get(param, {}).items():
                    if torch.is_tensor(value) and value.dim() and value.shape != param.shape:
                        raise ValueError(f"optimizer {key} of shape {list(value.shape)} for {list(param.shape)}")
    best = state["best"]
    if best["state"] is not None:
        model = stateful["model"].state_dict()
        if best["state"].keys() != model.keys() or any(best["state"][k].shape != v.shape for k, v in model.items()):
            raise ValueError("the best weights do not match the model's parameters")
    return Progress(state["epoch"] + 1, state["log"], best["metric"], best["epoch"], best["state"])


def _set_aside(path: Path, problem: str) -> Progress:
    """Rename a damaged checkpoint out of the way (kept for inspection) and start from the first epoch."""
    aside = path.with_name(f"{path.name}.damaged-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}")
    os.replace(path, aside)
    warn(
        f"{path}: damaged resume checkpoint, {problem}; set aside as {aside.name} (moved to the artifact root's "
        ".damaged/ once the artifact is built), training starts from epoch 1"
    )
    return Progress()


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


def _quiet(done: int, total: int) -> None:
    """The tick of a run nobody follows batch by batch."""


class Step(NamedTuple):
    """One optimizer step a trainer asks for."""

    loss: torch.Tensor  # what this process backpropagates (under torchrun: its share of the global batch's)
    terms: tuple[torch.Tensor, ...]  # the loss terms the log averages, in the order of `Trainer.terms`
    weight: float = 1.0  # this process's share of the global batch's mean (1 for a single process)
    seen: int = 0  # agent-windows the step trained on, for throughput columns


class Trainer(Protocol):
    """What a stage trains: its model, optimizer and schedule, the steps of an epoch, and its validation."""

    model: torch.nn.Module
    optimizer: torch.optim.Optimizer
    device: torch.device
    schedule: Schedule
    grad_clip: float
    terms: tuple[str, ...]  # the names of `Step.terms`

    def steps(self, epoch: int) -> tuple[int, Iterator[Step]]:
        """How many steps epoch `epoch` takes, and the steps, each computed when the loop asks for it."""
        ...

    def columns(
        self, epoch: int, sums: dict[str, float], seen: int, seconds: float, previous: dict[str, Any] | None
    ) -> dict[str, Any]:
        """The epoch's training columns of the log from its mean loss terms, the agent-windows it saw and its
        seconds (`previous`: the last row, for running totals over a resumed run)."""
        ...

    def validate(self) -> dict[str, float]:
        """Validation metrics after an epoch."""
        ...


def train_epoch(
    trainer: Trainer, epoch: int, tick: Callable[[int, int], None], previous: dict[str, Any] | None
) -> dict[str, Any]:
    """One epoch: each step at its scheduled rate, its loss terms averaged over the epoch (and the ranks)."""
    tic = time.perf_counter()
    count, steps = trainer.steps(epoch)
    sums, seen = dict.fromkeys(trainer.terms, 0.0), 0
    for index, step in enumerate(steps):
        rate = trainer.schedule.at(epoch, index)
        optimizer_step(trainer.model, trainer.optimizer, step.loss, rate, trainer.grad_clip)
        for name, value in zip(trainer.terms, step.terms, strict=True):
            sums[name] += value.item() * step.weight / count
        seen += step.seen
        tick(index + 1, count)
    sums = distributed.sum_over_ranks(sums, trainer.device)
    return trainer.columns(epoch, sums, seen, time.perf_counter() - tic, previous)


class Run(Protocol):
    """Where a training writes and whom it tells (a stage's StageContext is one)."""

    dir: Path
    scratch: Path
    on_progress: Callable[[str, int, int], None] | None
    on_epoch: Callable[[dict[str, Any]], None] | None


def fit(trainer: Trainer, run: Run, *, seed: int, best_by: str, log_name: str) -> Progress:
    """Train for the epochs of `trainer.schedule`, validating after each, resuming from the scratch checkpoint;
    returns the log and the best weights (lowest `trainer.validate()[best_by]`).

    The stages differ only in their data, model, loss and metrics, which their `trainer` holds (its steps,
    schedule, log columns and validation); this loop and `train_epoch` own the rest. Each epoch reseeds
    torch's global generator with `epoch_seed` and ends with a checkpoint of the model, the optimizer and the
    progress, so a run killed mid-epoch and started again redoes that epoch and ends with the same weights as
    an uninterrupted run. Log rows are (epoch, seconds, training columns, validation metrics); they go to
    `run.on_epoch`, TensorBoard (live under `run.scratch`, copied into `run.dir` at the end) and
    `run.dir / log_name`. `run.on_progress` gets ("epoch e/E", done, total) after each optimizer step.

    Under torchrun (`distributed`), rank 0 alone validates (its metrics are broadcast, so every rank keeps
    the same best epoch), writes the checkpoint, curves and log, and reports; every rank resumes from the
    one checkpoint, the others after rank 0 has read it (and set it aside when damaged).
    """
    model, scratch, leader = trainer.model, run.scratch, distributed.leader()
    on_progress = run.on_progress if leader else None
    stateful = {"model": model, "optimizer": trainer.optimizer}
    checkpoint = scratch / "last.pt"
    progress = _resume_everywhere(checkpoint, trainer.device, stateful)
    curves = Curves(scratch, progress.start_epoch) if leader else None
    epochs = trainer.schedule.epochs
    for epoch in range(progress.start_epoch, epochs):
        model.train()
        tic = time.perf_counter()
        # dropout and whatever else draws from the global generator (each rank its own stream)
        torch.manual_seed(distributed.rank_seed(epoch_seed(seed, epoch)))
        tick = partial(on_progress, f"epoch {epoch + 1}/{epochs}") if on_progress else _quiet
        trained = train_epoch(trainer, epoch, tick, progress.log[-1] if progress.log else None)
        metrics = distributed.broadcast(trainer.validate() if leader else None)
        row = {"epoch": epoch + 1, "seconds": round(time.perf_counter() - tic, 3), **trained, **metrics}
        progress.record(row, metrics[best_by], model)
        if curves is not None:
            curves.add(row)
            if run.on_epoch:
                run.on_epoch(row)
            save_progress(checkpoint, progress, epoch, stateful)
    if curves is not None:
        curves.finish(run.dir)
        write_csv(run.dir / log_name, progress.log)
    return progress


def _resume_everywhere(checkpoint: Path, device: torch.device, stateful: dict[str, Any]) -> Progress:
    """`resume` on rank 0, then on the other ranks (which must find the epoch rank 0 found)."""
    if not distributed.active():
        return resume(checkpoint, device, stateful)
    progress = resume(checkpoint, device, stateful) if distributed.leader() else None
    start = distributed.broadcast(progress.start_epoch if progress else None)
    if progress is None:
        progress = resume(checkpoint, device, stateful)
    if progress.start_epoch != start:
        raise IntegrityError(
            f"{checkpoint}: rank {distributed.rank()} resumes at epoch {progress.start_epoch + 1}, "
            f"rank 0 at {start + 1}; start the run again"
        )
    return progress
