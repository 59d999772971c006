"""Parallel cells: `reproduce --jobs 2` builds the same artifacts and tables as one job; a failed build
stops only what needs it; a Dask cluster runs the same grid and survives a worker killed mid-build."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from fftool import scheduler
from fftool.artifacts.store import ArtifactStore
from fftool.cli import app
from fftool.config import load_config
from fftool.reporting import ablation
from tests.test_maps import make_scene
from tests.test_reproduce import TINY_PIPELINE

pytestmark = pytest.mark.slow  # worker processes and a Dask cluster


@pytest.fixture
def profile(raw_tree: Path, tmp_path: Path) -> Path:
    make_scene(tmp_path / "scenes" / "zara1")
    path = tmp_path / "tiny.toml"
    path.write_text(TINY_PIPELINE.format(raw=str(raw_tree), scenes=str(tmp_path / "scenes")))
    return path


def _reproduce(profile: Path, root: Path, *extra: str) -> str:
    args = ["reproduce", str(profile), "--root", str(root), "--device", "cpu", "--threads", "1", *extra]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    return result.output


def _contents(root: Path) -> dict[str, dict[str, str]]:
    """Every stage artifact's data files by sha256, except what records when and how fast it ran: manifests
    (dates, times), TensorBoard event files (their names and records carry wall-clock times) and the timing
    columns of training logs, which are compared without them. Reports (their wall time) are compared apart."""
    found = {}
    for manifest in root.glob("*/*/manifest.json"):
        if manifest.parts[-3] in ("reports", "report"):
            continue
        files = json.loads(manifest.read_text())["files"]
        contents = {name: f["sha256"] for name, f in files.items() if not name.startswith("tensorboard/")}
        for log in manifest.parent.glob("*log.csv"):
            table = pd.read_csv(log)
            timing = [c for c in table.columns if "seconds" in c or c.endswith("_per_s")]
            contents[log.name] = table.drop(columns=timing).to_csv(index=False)
        found[f"{manifest.parts[-3]}/{manifest.parts[-2]}"] = contents
    return found


def _tables(report: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(report.glob("table*.*"))}


def test_two_jobs_build_what_one_job_builds(profile: Path, tmp_path: Path) -> None:
    _reproduce(profile, tmp_path / "one")
    output = _reproduce(profile, tmp_path / "two", "--jobs", "2")
    assert "stage builds to run on 2 local worker processes, 1 torch thread(s) each" in output
    one, two = _contents(tmp_path / "one"), _contents(tmp_path / "two")
    assert len(one) == 11 and one == two  # tracks, windows, forces, maps, goal, goals, 2 CVAEs, 3 evaluations
    assert _tables(tmp_path / "one" / "reports" / "tiny") == _tables(tmp_path / "two" / "reports" / "tiny")
    assert len(list((tmp_path / "two" / scheduler.LOGS).glob("*.log"))) == 11  # each build's output, kept
    again = _reproduce(profile, tmp_path / "two", "--jobs", "2")
    assert "0 of 11 stage builds to run" in again


def test_a_failed_build_stops_only_what_needs_it(profile: Path, tmp_path: Path) -> None:
    (tmp_path / "scenes" / "zara1" / "reference.png").write_bytes(b"not a PNG")  # the maps stage fails on it
    root = tmp_path / "artifacts"
    args = ["reproduce", str(profile), "--root", str(root), "--device", "cpu", "--jobs", "2"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 1
    error = result.output.strip().splitlines()[-1]
    assert error.startswith("Error: 1 of 11 stage builds failed (scene maps") and "3 were not built" in error
    assert "reference.png" in result.output  # the failure's own reason, and its log file
    assert "not built: train goal U-Net (zara1)" in " ".join(result.output.split())
    store = ArtifactStore(root)
    assert not store.list("maps") and not store.list("goal") and len(store.list("cvae")) == 2
    assert len(store.list("evaluate")) == 2  # cv and the baseline; dr needs the goals
    assert not list(root.glob(".incomplete/*"))


def test_threads_share_the_cores() -> None:
    assert scheduler.threads_per_job(1) == scheduler.cores()
    assert scheduler.threads_per_job(2) == max(1, scheduler.cores() // 2)
    assert scheduler.threads_per_job(64) == 1
    assert scheduler.threads_per_job(2, threads=3) == 3


def test_shared_stages_are_planned_once(profile: Path) -> None:
    cfg = load_config(profile)
    grid = [(cell.cfg, cell.benchmark) for cell in ablation.cells(cfg, ["zara1"], ["dr"])]
    nodes = scheduler.plan(grid).nodes
    assert sorted(stage for stage, _ in nodes) == sorted(
        ["tracks", "windows", "forces", "maps", "goal", "goals", "cvae", "cvae", "evaluate", "evaluate", "evaluate"]
    )
    for node in nodes.values():
        assert node.needs <= set(nodes)


def _kill_first_cvae_build(root: Path, killed: list[int], stop: threading.Event) -> None:
    """Kill the worker process building the first CVAE, once its build folder appears."""
    while not stop.is_set() and not killed:
        for folder in root.glob(".incomplete/cvae-*"):
            pid = int(folder.name.rsplit("-", 1)[-1])
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)
            return
        time.sleep(0.05)


def test_a_dask_cluster_runs_the_grid_and_retries_a_killed_worker(profile: Path, tmp_path: Path) -> None:
    distributed = pytest.importorskip("distributed", reason="the cluster extra (pip install 'fftool[cluster]')")
    root = tmp_path / "artifacts"
    killed: list[int] = []
    stop = threading.Event()
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        watcher = threading.Thread(target=_kill_first_cvae_build, args=(root, killed, stop), daemon=True)
        watcher.start()
        try:
            output = _reproduce(profile, root, "--scheduler", cluster.scheduler_address)
        finally:
            stop.set()
            watcher.join()
    assert killed, "no CVAE build was caught to kill"
    assert "stage builds to run on the Dask cluster" in output
    assert _contents(root) == _contents_of_one_job(profile, tmp_path / "reference")
    assert not list(root.glob(".incomplete/*"))  # the killed build's folder was removed by the retry


def _contents_of_one_job(profile: Path, root: Path) -> dict[str, dict[str, str]]:
    _reproduce(profile, root)
    return _contents(root)


def test_every_error_crosses_a_process_boundary() -> None:
    """A worker hands its error back pickled; one that does not unpickle breaks the whole process pool."""
    import pickle

    from fftool import errors

    classes = [c for c in vars(errors).values() if isinstance(c, type) and issubclass(c, errors.FftoolError)]
    assert len(classes) >= 8
    for cls in classes:
        error = cls("a.txt", "bad", 3) if cls is errors.RawDataError else cls("what went wrong")
        again = pickle.loads(pickle.dumps(error))
        assert type(again) is cls and str(again) == str(error)
