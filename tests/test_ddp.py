"""Data-parallel training (torchrun, docs/scaling.md): 2 gloo ranks on the CPU, on tiny synthetic data.

Ranks are processes with torchrun's environment (WORLD_SIZE, RANK, LOCAL_RANK, MASTER_ADDR/PORT), forked
from a fork server that imported torch and fftool once: a fork of the test process itself would inherit the
threads of pytest-xdist's worker (a rank could hang on a lock one of them held), and spawned ranks re-import
everything (~10 s each here). The parent never joins a process group.
What "the same step" means: the global batch is the single-process batch. For the goal U-Net (order and
augmentation drawn for the global batch) the 2-rank step is compared with today's single-process step.
For the CVAE each rank draws its windows' rotations and latent samples from its own generator (seed +
rank · 2**40), and dropout is 0; the reference is one process computing the global batch's mean loss with
each window's noise drawn from its rank's generator, one backward, one optimizer step.
"""

from __future__ import annotations

import faulthandler
import multiprocessing
import os
import shutil
import signal
import socket
from pathlib import Path
from typing import Any

import pytest
import torch

from fftool import pipeline
from fftool.artifacts.store import ArtifactStore
from fftool.config import CVAEConfig, ForcesConfig, GoalConfig, GoalsConfig, load_config
from fftool.learning import cvae_model, training
from fftool.learning.features import prepare
from fftool.learning.training import epoch_seed, generator, lr_factor, optimizer_step, train_epoch
from fftool.stages import cvae, goal

from .conftest import make_raw_tree
from .test_maps import make_scene

pytestmark = pytest.mark.slow  # torchrun ranks in their own processes

WORLD = 2
CPU = torch.device("cpu")
CVAE = CVAEConfig(
    d_model=16, n_heads=2, d_ff=32, n_layers=1, z_dim=4, k=3, train_k=2, epochs=2, batch_windows=8, lr=1e-3,
    val_max_windows=8, dropout=0.0, max_train_windows=24,
)  # fmt: skip
ONE_STEP = CVAE.model_copy(update={"max_train_windows": 8, "epochs": 1})  # one batch of 8 windows
GOAL = GoalConfig(
    resolution_m=0.5, crop_cells=16, widths=(4, 8, 8), epochs=1, batch_size=16, lr=3e-3, train_stride=1, val_max=0,
    max_train=16,
)  # fmt: skip
SAMPLING = GoalsConfig(k=5, samples=200, kmeans_iterations=5)


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A store with windows and maps of the tiny synthetic tree (what both trainings read)."""
    base = tmp_path_factory.mktemp("ddp")
    make_scene(base / "scenes" / "zara1")
    cfg = _config(base)
    pipeline.run(cfg, ArtifactStore(base / "artifacts"), ["windows", "maps"])
    return base


def _config(base: Path) -> Any:
    if not (base / "raw").exists():
        make_raw_tree(base / "raw")
    cfg = load_config(None, [f"data.raw_dir={str(base / 'raw')!r}", f"data.scenes_dir={str(base / 'scenes')!r}"])
    return cfg.model_copy(update={"cvae": CVAE})


def _inputs(store_root: Path) -> dict[str, Any]:
    store = ArtifactStore(store_root)
    return {kind: store.list(kind)[0] for kind in ("windows", "maps")}


def _as_rank(rank: int, port: int) -> None:
    """This process becomes rank `rank` of WORLD, as torchrun would start it."""
    os.environ.update(
        WORLD_SIZE=str(WORLD), RANK=str(rank), LOCAL_RANK=str(rank), MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port)
    )
    torch.set_num_threads(1)


def _spawn(target: Any, *args: Any, timeout: float = 120, grace: float | None = None) -> list[int | None]:
    """Run `target(rank, port, *args)` in WORLD processes; their exit codes. With `grace`, the other ranks get
    that long once rank 0 has ended, then they are killed (a killed rank 0 leaves them waiting). A rank still
    running 10 s before its deadline prints its threads' stacks."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["torch", "fftool.pipeline", __name__])
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    procs = [context.Process(target=_rank, args=(timeout, target, rank, port, *args)) for rank in range(WORLD)]
    for proc in procs:
        proc.start()
    try:
        procs[0].join(timeout)
        for proc in procs[1:]:
            proc.join(grace if grace is not None else timeout)
    finally:
        for proc in procs:
            if proc.is_alive():
                proc.kill()
                proc.join()
    return [proc.exitcode for proc in procs]


def _rank(timeout: float, target: Any, *args: Any) -> None:
    faulthandler.dump_traceback_later(max(timeout - 10, 1), exit=False)
    target(*args)


def _first_steps(rank: int, port: int, store_root: Path, out: Path) -> None:
    """One optimizer step of each training on this rank's share of the global batch; rank 0 saves the
    weights, gradients and logged losses."""
    _as_rank(rank, port)
    from fftool.learning import distributed

    distributed.join("cpu")
    inputs = _inputs(store_root)
    cvae_trainer = cvae._trainer(ONE_STEP, ForcesConfig(), "zara1", inputs["windows"], None, CPU)
    cvae_row = train_epoch(cvae_trainer, 0, lambda done, total: None, None)
    goal_trainer = goal._trainer(GOAL, SAMPLING, "zara1", inputs["windows"], inputs["maps"], CPU)
    goal_row = train_epoch(goal_trainer, 0, lambda done, total: None, None)
    if rank == 0:
        torch.save({"cvae": _weights_and_grads(cvae_trainer.model), "cvae_row": cvae_row,
                    "goal": _weights_and_grads(goal_trainer.model), "goal_row": goal_row}, out)  # fmt: skip
    distributed.leave()


def _weights_and_grads(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {
        **{name: p.detach().clone() for name, p in model.named_parameters()},
        **{f"{name}.grad": p.grad.clone() for name, p in model.named_parameters()},
    }


def test_the_first_step_of_two_ranks_is_the_single_process_step_on_their_union(root: Path) -> None:
    out = root / "first_steps.pt"
    assert _spawn(_first_steps, root / "artifacts", out) == [0, 0]
    ranks = torch.load(out, weights_only=True)
    inputs = _inputs(root / "artifacts")

    # the goal U-Net: today's single-process step on the global batch of 16 windows
    single = goal._trainer(GOAL, SAMPLING, "zara1", inputs["windows"], inputs["maps"], CPU)
    row = train_epoch(single, 0, lambda done, total: None, None)
    torch.testing.assert_close(ranks["goal"], _weights_and_grads(single.model))
    assert ranks["goal_row"] == pytest.approx(row, rel=1e-5)

    # the CVAE: one process, the union of both ranks' windows, each window's noise from its rank's generator
    reference = cvae._trainer(ONE_STEP, ForcesConfig(), "zara1", inputs["windows"], None, CPU)
    plan, rng = cvae_model.epoch_plan(reference.train, ONE_STEP, 0, reference.per_epoch)
    assert [len(members) for members in plan] == [8]
    batch = reference.train.batch(plan[0], ONE_STEP.max_agents, rng)
    total = torch.zeros(())
    for rank in range(WORLD):
        rows = torch.arange(rank, len(plan[0]), WORLD)
        gen = generator(epoch_seed(ONE_STEP.seed, 0) + rank * 2**40, CPU)
        part = batch.map(lambda t, rows=rows: t[rows])
        prepared = prepare(part, "baseline", reference.obs_len, rotate=ONE_STEP.rotate, generator=gen)
        parts = cvae_model.training_loss(reference.model, prepared, ONE_STEP, None, None, gen)
        total = total + parts.total * len(rows) / len(plan[0])  # the global batch's mean over windows
    factor = lr_factor(ONE_STEP.schedule, 0, sum(reference.schedule.steps_per_epoch), ONE_STEP.warmup_fraction)
    optimizer_step(reference.model, reference.optimizer, total, ONE_STEP.lr * factor, ONE_STEP.grad_clip)
    torch.testing.assert_close(ranks["cvae"], _weights_and_grads(reference.model))
    assert ranks["cvae_row"]["train_loss"] == pytest.approx(total.item(), rel=1e-5)
    assert ranks["cvae_row"]["agent_windows_seen"] == int(batch.agent_mask.sum())


def _train(rank: int, port: int, base: Path, store_root: Path, marks: Path, die_after_epoch: int | None) -> None:
    """`fftool train-cvae` as one torchrun rank; records which ranks opened a build or took a lock; rank 0 is
    killed (SIGKILL) right after writing the checkpoint of epoch `die_after_epoch` (0-based), if given."""
    _as_rank(rank, port)
    build, lock = ArtifactStore.build, ArtifactStore.lock

    def marked(method: Any, name: str) -> Any:
        def call(self: ArtifactStore, *args: Any, **kwargs: Any) -> Any:
            (marks / f"{name}-rank{rank}").touch()
            return method(self, *args, **kwargs)

        return call

    ArtifactStore.build, ArtifactStore.lock = marked(build, "build"), marked(lock, "lock")  # type: ignore[method-assign]
    if die_after_epoch is not None and rank == 0:
        save = training.save_progress

        def save_then_die(path: Path, progress: Any, epoch: int, stateful: Any) -> None:
            save(path, progress, epoch, stateful)
            if epoch == die_after_epoch:
                os.kill(os.getpid(), signal.SIGKILL)

        training.save_progress = save_then_die  # type: ignore[assignment]
    cfg = _config(base)
    pipeline.run(cfg, ArtifactStore(store_root), ["cvae"], runtime=pipeline.Runtime("cpu"), upstream=False,
                 benchmark="zara1")  # fmt: skip


def _the_cvae(store_root: Path) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
    (artifact,) = ArtifactStore(store_root).list("cvae")
    return artifact.manifest.stats, torch.load(artifact.file("model.pt"), weights_only=True)["state_dict"]


def test_a_killed_two_rank_training_resumes_and_rank_0_alone_installs(root: Path, tmp_path: Path) -> None:
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    for store_root in (whole, killed):
        shutil.copytree(root / "artifacts", store_root)
        (store_root.parent / f"{store_root.name}-marks").mkdir()

    assert _spawn(_train, root, whole, tmp_path / "whole-marks", None) == [0, 0]
    stats, weights = _the_cvae(whole)
    assert (stats["world_size"], stats["backend"], stats["resumed_from_epoch"]) == (2, "gloo", 0)
    assert [row["epoch"] for row in stats["log"]] == [1, 2]
    # rank 0 alone opened the build and took the fingerprint's lock; nothing is left half-built
    assert sorted(p.name for p in (tmp_path / "whole-marks").iterdir()) == ["build-rank0", "lock-rank0"]
    assert not (whole / ".incomplete").exists() and not (whole / ".scratch").exists()

    codes = _spawn(_train, root, killed, tmp_path / "killed-marks", 0, grace=15)
    assert codes[0] == -signal.SIGKILL
    assert not ArtifactStore(killed).list("cvae")
    (checkpoint,) = (killed / ".scratch").glob("cvae-*/last.pt")
    assert torch.load(checkpoint, weights_only=True)["epoch"] == 0

    assert _spawn(_train, root, killed, tmp_path / "killed-marks", None) == [0, 0]
    resumed, resumed_weights = _the_cvae(killed)
    assert resumed["resumed_from_epoch"] == 1 and [row["epoch"] for row in resumed["log"]] == [1, 2]
    torch.testing.assert_close(resumed_weights, weights, rtol=0, atol=0)
    drop = lambda log: [{k: v for k, v in row.items() if "seconds" not in k and "per_s" not in k} for row in log]  # noqa: E731
    assert drop(resumed["log"]) == drop(stats["log"])
    assert not (killed / ".incomplete").exists() and not (killed / ".scratch").exists()
    assert sorted(p.name for p in (tmp_path / "killed-marks").iterdir()) == ["build-rank0", "lock-rank0"]
