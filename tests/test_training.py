"""The shared epoch loop (resumes to the same weights) and checkpoints: atomic per-process writes, damaged resume
files set aside, damaged model files refused."""

from __future__ import annotations

import csv
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from fftool.artifacts.schema import TENSORBOARD_DIR
from fftool.errors import IntegrityError
from fftool.learning import training
from fftool.learning.training import Progress, fit, model_file, resume, save_checkpoint, save_progress


def _stateful(width: int = 3) -> dict:
    torch.manual_seed(0)
    model = torch.nn.Linear(width, 2)
    return {"model": model, "optimizer": torch.optim.Adam(model.parameters(), lr=0.1)}


def _step(stateful: dict) -> None:
    stateful["optimizer"].zero_grad()
    stateful["model"](torch.ones(1, stateful["model"].in_features)).sum().backward()
    stateful["optimizer"].step()


def _checkpoint(path: Path, width: int = 3) -> None:
    """Two finished epochs of a trained tiny model, as the training stages write them."""
    stateful = _stateful(width)
    progress = Progress()
    for epoch in range(2):
        _step(stateful)
        progress.record({"epoch": epoch + 1}, 1.0 / (epoch + 1), stateful["model"])
        save_progress(path, progress, epoch, stateful)


@pytest.fixture
def warnings(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    said: list[str] = []
    monkeypatch.setattr(training, "warn", said.append)
    return said


def test_a_checkpoint_resumes_after_its_last_epoch(tmp_path: Path, warnings: list[str]) -> None:
    _checkpoint(tmp_path / "last.pt")
    stateful = _stateful()
    progress = resume(tmp_path / "last.pt", torch.device("cpu"), stateful)
    assert (progress.start_epoch, progress.best_epoch, len(progress.log)) == (2, 2, 2)
    assert stateful["optimizer"].state_dict()["state"][0]["step"] == 2
    assert warnings == [] and sorted(p.name for p in tmp_path.iterdir()) == ["last.pt"]


def test_a_save_leaves_others_temporaries_alone_and_the_same_weights_are_the_same_bytes(tmp_path: Path) -> None:
    other = tmp_path / ".last.pt.x1y2z3.partial"  # another process, half-way through its own save
    other.write_bytes(b"half")
    state = {"epoch": 0, "weights": torch.arange(4.0)}
    save_checkpoint(tmp_path / "last.pt", state)
    save_checkpoint(tmp_path / "elsewhere" / "model.pt", state)  # torch would name its archive after the path
    assert (tmp_path / "last.pt").read_bytes() == (tmp_path / "elsewhere" / "model.pt").read_bytes()
    assert torch.load(tmp_path / "last.pt", weights_only=True)["epoch"] == 0
    assert other.read_bytes() == b"half"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".last.pt.x1y2z3.partial", "elsewhere", "last.pt"]


def test_a_failed_save_keeps_the_old_checkpoint_and_no_partial_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    save_checkpoint(tmp_path / "last.pt", {"epoch": 0})

    def full_disk(self: Path, data: bytes) -> None:
        with self.open("wb") as handle:
            handle.write(data[:4])
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Path, "write_bytes", full_disk)
    with pytest.raises(OSError, match="No space left"):
        save_checkpoint(tmp_path / "last.pt", {"epoch": 1})
    assert [p.name for p in tmp_path.iterdir()] == ["last.pt"]
    assert torch.load(tmp_path / "last.pt", weights_only=True) == {"epoch": 0}


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _edit(change: Callable[[dict], None]) -> Callable[[Path], None]:
    def damage(path: Path) -> None:
        state = torch.load(path, weights_only=True)
        change(state)
        torch.save(state, path)

    return damage


def _moments(state: dict) -> None:
    state["states"]["optimizer"]["state"][0]["exp_avg"] = torch.zeros(7)


DAMAGE = {
    "truncated": (_truncate, "does not load"),
    "garbage": (lambda path: path.write_bytes(os.urandom(3000)), "does not load"),
    "empty": (lambda path: path.write_bytes(b""), "does not load"),
    "text": (lambda path: path.write_text("epoch = 3\n"), "does not load"),
    "another model": (lambda path: _checkpoint(path, width=5), "size mismatch for weight"),
    "missing keys": (_edit(lambda state: state.pop("best")), "KeyError: 'best'"),
    "optimizer moments": (_edit(_moments), "optimizer exp_avg of shape [7] for [2, 3]"),
    "best weights": (_edit(lambda s: s["best"]["state"].pop("bias")), "best weights do not match"),
}


@pytest.mark.parametrize("kind", DAMAGE)
def test_a_damaged_resume_checkpoint_is_set_aside_and_training_starts_over(
    tmp_path: Path, warnings: list[str], kind: str
) -> None:
    damage, problem = DAMAGE[kind]
    path = tmp_path / "last.pt"
    _checkpoint(path)
    damage(path)
    damaged = path.read_bytes()
    stateful = _stateful()
    fresh = {name: obj.state_dict() for name, obj in _stateful().items()}

    progress = resume(path, torch.device("cpu"), stateful)

    assert progress == Progress()  # epoch 0, empty log, no best weights
    assert not path.exists()
    (aside,) = tmp_path.glob("last.pt.damaged-*")
    assert aside.name.endswith(f"-{os.getpid()}") and aside.read_bytes() == damaged  # kept, not deleted
    assert len(warnings) == 1 and warnings[0].startswith(f"{path}: damaged resume checkpoint")
    assert problem in warnings[0] and aside.name in warnings[0] and "weights_only" not in warnings[0]
    for key, value in fresh["model"].items():  # a partial load was undone: the run starts from fresh weights
        torch.testing.assert_close(stateful["model"].state_dict()[key], value)
    assert stateful["optimizer"].state_dict()["state"] == {}
    _step(stateful)  # and trains
    save_progress(path, progress, 0, stateful)
    assert resume(path, torch.device("cpu"), _stateful()).start_epoch == 1


UNLOADABLE = "damaged or modified: it does not load as tensors and plain values"


class _Tampered:
    """Any object a pickle can smuggle in: weights-only loading must refuse it."""


@pytest.mark.parametrize(
    ("kind", "problem"),
    [
        ("garbage", UNLOADABLE),
        ("truncated", UNLOADABLE),
        ("pickled object", UNLOADABLE),
        ("wrong contents", "its contents do not fit the model (KeyError: 'weights')"),
    ],
)
def test_a_damaged_model_file_is_one_integrity_error(tmp_path: Path, kind: str, problem: str) -> None:
    path = tmp_path / "model.pt"
    save_checkpoint(path, {"weights": torch.ones(3)})
    if kind == "garbage":
        path.write_bytes(os.urandom(500))
    elif kind == "truncated":
        _truncate(path)
    elif kind == "pickled object":
        torch.save({"weights": _Tampered()}, path)
    else:
        save_checkpoint(path, {"state_dict": {}})
    with (
        pytest.raises(IntegrityError) as caught,
        model_file(path, torch.device("cpu"), "fftool train-x --force") as saved,
    ):
        saved["weights"]
    message = str(caught.value)
    assert message == f"{path}: not a valid fftool checkpoint, {problem}; rebuild it with `fftool train-x --force`"
    assert "weights_only" not in message


def test_a_valid_model_file_loads_and_other_errors_pass_through(tmp_path: Path) -> None:
    path = tmp_path / "model.pt"
    save_checkpoint(path, {"weights": torch.ones(3)})
    with model_file(path, torch.device("cpu"), "fftool train-x --force") as saved:
        assert torch.equal(saved["weights"], torch.ones(3))
    with pytest.raises(ZeroDivisionError), model_file(path, torch.device("cpu"), "fftool train-x --force"):
        _ = 1 / 0
    with pytest.raises(FileNotFoundError):
        model_file(tmp_path / "missing.pt", torch.device("cpu"), "fftool train-x --force").__enter__()


def _fit(
    tmp_path: Path,
    name: str,
    epochs: int,
    on_progress: Callable[[str, int, int], None] | None = None,
    rows: list[dict] | None = None,
) -> tuple[Progress, dict]:
    """A tiny regression trained by `fit`: dropout draws from torch's global generator, each epoch's batch
    order from (seed, epoch); a column that adds up over epochs. Returns the progress and the final weights."""
    torch.manual_seed(0)
    x = torch.randn(32, 3)
    y = x.sum(-1, keepdim=True)
    model = torch.nn.Sequential(torch.nn.Linear(3, 8), torch.nn.Dropout(0.5), torch.nn.Linear(8, 1))
    optimizer = torch.optim.Adam(model.parameters(), lr=0.01)

    def steps(epoch: int) -> tuple[int, Iterator[training.Step]]:
        assert model.training
        order = torch.randperm(32, generator=training.generator(training.epoch_seed(7, epoch), torch.device("cpu")))
        batches = (order[b * 8 : (b + 1) * 8] for b in range(4))
        losses = (((model(x[index]) - y[index]) ** 2).mean() for index in batches)
        return 4, (training.Step(loss, (loss,), seen=8) for loss in losses)

    def columns(epoch: int, sums: dict, seen: int, seconds: float, previous: dict | None) -> dict:
        return {"train_loss": sums["loss"], "batches_seen": (previous["batches_seen"] if previous else 0) + seen // 8}

    def validate() -> dict[str, float]:
        model.eval()
        with torch.no_grad():
            return {"val_mse": float(((model(x) - y) ** 2).mean())}

    out = tmp_path / name
    out.mkdir()
    schedule = training.Schedule(0.01, "constant", (4,) * epochs)
    trainer = SimpleNamespace(
        model=model, optimizer=optimizer, device=torch.device("cpu"), schedule=schedule, grad_clip=1.0,
        terms=("loss",), steps=steps, columns=columns, validate=validate,
    )  # fmt: skip
    run = SimpleNamespace(
        dir=out,
        scratch=tmp_path / "scratch",
        on_progress=on_progress,
        on_epoch=None if rows is None else rows.append,
    )
    progress = fit(trainer, run, seed=7, best_by="val_mse", log_name="log.csv")
    return progress, model.state_dict()


def _timeless(log: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if k != "seconds"} for row in log]


def test_the_loop_logs_every_epoch_and_keeps_the_best_weights(tmp_path: Path) -> None:
    rows: list[dict] = []
    progress, _ = _fit(tmp_path, "run", 3, rows=rows)
    assert rows == progress.log
    assert [list(row) for row in rows] == [["epoch", "seconds", "train_loss", "batches_seen", "val_mse"]] * 3
    assert [row["batches_seen"] for row in rows] == [4, 8, 12]
    best = min(rows, key=lambda row: row["val_mse"])
    assert (progress.best_epoch, progress.best_metric) == (best["epoch"], best["val_mse"])
    with open(tmp_path / "run" / "log.csv") as handle:
        logged = list(csv.DictReader(handle))
    assert [float(row["val_mse"]) for row in logged] == [row["val_mse"] for row in rows]
    assert (tmp_path / "run" / TENSORBOARD_DIR).is_dir()
    assert torch.load(tmp_path / "scratch" / "last.pt", weights_only=True)["epoch"] == 2


def test_an_interrupted_loop_resumes_to_the_same_weights_and_log(tmp_path: Path) -> None:
    reference, weights = _fit(tmp_path, "reference", 3)
    (tmp_path / "scratch" / "last.pt").unlink()
    phases: list[str] = []

    def interrupt(phase: str, done: int, total: int) -> None:
        phases.append(phase)
        if phase == "epoch 3/3" and done == 2:  # mid-epoch: two of its four steps taken
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _fit(tmp_path, "interrupted", 3, interrupt)
    assert phases == ["epoch 1/3"] * 4 + ["epoch 2/3"] * 4 + ["epoch 3/3"] * 2
    resumed, resumed_weights = _fit(tmp_path, "resumed", 3)
    assert resumed.start_epoch == 2 and _timeless(resumed.log) == _timeless(reference.log)
    assert all(torch.equal(weights[key], resumed_weights[key]) for key in weights)
    assert resumed.best_epoch == reference.best_epoch
    assert all(torch.equal(reference.best_state[key], resumed.best_state[key]) for key in weights)
