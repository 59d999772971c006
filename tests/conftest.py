"""Shared fixtures: a tiny synthetic raw tree (all 8 sources × all/train/val), a store on tmp_path, and what
is built once per test run and copied or read by the tests: the synthetic tree's tracks, windows and forces
(`built_store`), and tiny trained CVAEs (`tiny_cvaes`)."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from filelock import FileLock

from fftool.artifacts.store import ArtifactStore
from fftool.dataset.scenes import SOURCES, raw_relpath

REAL_RAW = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "eth_ucy" / "raw"


def write_rows(path: Path, rows: list[tuple[float, float, float, float]], sep: str = "\t") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(sep.join(f"{v}" for v in row) + "\n" for row in rows))
    return path


def walker_rows(n_peds: int, n_frames: int, stride: int = 10, seed: int = 0) -> list[tuple[float, ...]]:
    """Straight walkers: ped p is present from frame p*stride for n_frames - p frames."""
    rng = np.random.default_rng(seed)
    rows = []
    for ped in range(1, n_peds + 1):
        start = ped - 1
        velocity = rng.uniform(-1.0, 1.0, size=2)
        origin = rng.uniform(0.0, 10.0, size=2)
        for step in range(start, n_frames):
            x, y = origin + velocity * (step - start) * 0.4
            rows.append((step * stride, ped, round(float(x), 2), round(float(y), 2)))
    rows.sort()
    return rows


def make_raw_tree(root: Path, n_peds: int = 3, n_frames: int = 50, split_frame: int = 30) -> Path:
    """All 24 raw files: each source's all_data, and train/val split in time at `split_frame` steps."""
    for index, source in enumerate(SOURCES):
        rows = walker_rows(n_peds, n_frames, seed=index)
        write_rows(root / raw_relpath(source, "all"), rows)
        write_rows(root / raw_relpath(source, "train"), [r for r in rows if r[0] < split_frame * 10])
        write_rows(root / raw_relpath(source, "val"), [r for r in rows if r[0] >= split_frame * 10])
    return root


@pytest.fixture
def raw_tree(tmp_path: Path) -> Path:
    return make_raw_tree(tmp_path / "raw")


@pytest.fixture
def store(tmp_path: Path) -> ArtifactStore:
    return ArtifactStore(tmp_path / "artifacts")


@pytest.fixture
def real_raw() -> Path:
    """The real ETH/UCY raw files; CI sets FFTOOL_REQUIRE_DATA=1 so their absence fails, not skips."""
    if not REAL_RAW.is_dir():
        if os.environ.get("FFTOOL_REQUIRE_DATA"):
            pytest.fail(f"real data required but not found at {REAL_RAW.resolve()}")
        pytest.skip(f"real ETH/UCY data not found at {REAL_RAW.resolve()}")
    return REAL_RAW.resolve()


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under root with its bytes: to prove a failed command changed nothing.

    The store's empty lock files (`.locks/`) are left out: they hold no data and must outlive builds.
    """
    if not root.exists():
        return {}
    files = (p for p in sorted(root.rglob("*")) if p.is_file() and ".locks" not in p.relative_to(root).parts)
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in files}


def _once_per_run(factory: pytest.TempPathFactory, worker_id: str, name: str, build: Callable[[Path], str]) -> Path:
    """A folder `name` that `build(folder)` fills once for the whole run (pytest-xdist workers share it through a
    lock); `build` returns the text of `done.txt`, which marks it finished."""
    base = factory.getbasetemp()
    shared = (base.parent if worker_id != "master" else base) / name
    with FileLock(f"{shared}.lock"):
        if not (shared / "done.txt").is_file():
            (shared / "done.txt").write_text(build(shared))
    return shared


@pytest.fixture(scope="session")
def _synthetic_forces(tmp_path_factory: pytest.TempPathFactory, worker_id: str) -> Path:
    from fftool import pipeline
    from fftool.config import load_config

    def build(folder: Path) -> str:
        cfg = load_config(None, [f"data.raw_dir={str(make_raw_tree(folder / 'raw'))!r}"])
        pipeline.run(cfg, ArtifactStore(folder / "artifacts"), ["forces"])
        return "forces"

    return _once_per_run(tmp_path_factory, worker_id, "synthetic-forces", build)


@pytest.fixture
def built_store(_synthetic_forces: Path, tmp_path: Path) -> ArtifactStore:
    """A store on tmp_path already holding the `raw_tree` fixture's tracks, windows and forces under the default
    configuration (a copy of one built once per run: raw files enter fingerprints by content, so
    `pipeline.run(cfg, built_store, ...)` with `data.raw_dir` at `raw_tree` finds them built)."""
    shutil.copytree(_synthetic_forces / "artifacts", tmp_path / "artifacts", ignore=shutil.ignore_patterns(".locks"))
    return ArtifactStore(tmp_path / "artifacts")


# A CVAE that trains in seconds on the synthetic walkers: its weights need not be good, only fixed.
TINY_CVAE = [
    "cvae.d_model=16", "cvae.n_heads=2", "cvae.d_ff=32", "cvae.n_layers=1", "cvae.z_dim=4", "cvae.epochs=1",
    "cvae.train_k=2", "cvae.max_train_windows=64", "cvae.val_max_windows=4", "cvae.output='cv_residual'",
]  # fmt: skip


@pytest.fixture(scope="session")
def tiny_cvaes(_synthetic_forces: Path, tmp_path_factory: pytest.TempPathFactory, worker_id: str) -> dict[str, object]:
    """{"root": a store, "baseline": id, "dr": id}: tiny zara1 CVAEs, trained once for the whole run over a copy
    of the synthetic forces store. Tests read them; a test that changes a file copies the folder first."""
    from fftool import pipeline
    from fftool.config import load_config, predictor_config

    def build(folder: Path) -> str:
        cfg = load_config(None, [f"data.raw_dir={str(_synthetic_forces / 'raw')!r}", *TINY_CVAE])
        shutil.copytree(_synthetic_forces / "artifacts", folder / "artifacts", ignore=shutil.ignore_patterns(".locks"))
        store = ArtifactStore(folder / "artifacts")
        built = {
            v: pipeline.run(predictor_config(cfg, v), store, ["cvae"], benchmark="zara1") for v in ("baseline", "dr")
        }
        return "\n".join(f"{v} {b['cvae'].id}" for v, b in built.items())

    shared = _once_per_run(tmp_path_factory, worker_id, "tiny-cvaes", build)
    ids = dict(line.split() for line in (shared / "done.txt").read_text().splitlines())
    return {"root": shared / "artifacts", **ids}
