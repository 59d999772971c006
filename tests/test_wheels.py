"""fftool installed like any package: its two wheels into a fresh folder, used from a folder that is neither the
checkout nor beside the benchmark data, list, install, load and predict with a shipped model by name."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fftool import __version__

REPO = Path(__file__).resolve().parents[1]


def _build_wheels(out: Path) -> list[Path]:
    spec = importlib.util.spec_from_file_location("build_wheels", REPO / "tools/build_wheels.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.build(out)


@pytest.mark.slow
def test_the_installed_wheels_list_install_and_predict_by_name_without_the_data(tmp_path: Path) -> None:
    code, models = _build_wheels(tmp_path / "dist")
    site = tmp_path / "site"
    pip = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index", "--target", str(site)]
    subprocess.run([*pip, str(code), str(models)], check=True)
    work = tmp_path / "work"  # no checkout around it, no ../shared/data beside it
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("FFTOOL_MODELS", "FFTOOL_ARTIFACTS")}
    env |= {"PYTHONPATH": str(site), "OMP_NUM_THREADS": "1"}

    def python(*args: str) -> subprocess.CompletedProcess[str]:
        done = subprocess.run([sys.executable, *args], cwd=work, env=env, capture_output=True, text=True, timeout=240)
        assert done.returncode == 0, done.stdout + done.stderr
        return done

    def fftool(*args: str) -> str:
        done = python("-m", "fftool", *args)
        return done.stdout + done.stderr

    where = python("-c", "import fftool, fftool_models; print(fftool.__file__, fftool_models.MODELS)").stdout.split()
    assert all(Path(p).is_relative_to(site) for p in where)  # the installed copies, not the checkout
    assert fftool("--version").strip() == f"fftool {__version__}; models: fftool-models {__version__} ({where[1]})"
    listing = fftool("models", "list")
    assert "cpu/zara1/dr " in listing and "orphaned " not in listing.replace("orphaned:", "")
    assert "model(s) installed" in fftool("models", "install", "--root", "store")
    rows = [
        (f"{t * 0.4:.1f}", agent, f"{agent + 0.5 * t:.2f}", f"{-agent + 0.1 * t:.2f}")
        for t in range(8)
        for agent in (1, 2)
    ]
    (work / "tracks.csv").write_text("time,agent,x,y\n" + "".join(",".join(map(str, r)) + "\n" for r in rows))
    fftool("predict", "tracks.csv", "--model", "cpu/zara1/dr", "--out", "futures.parquet")
    read = "import pandas as p; f = p.read_parquet('futures.parquet'); print(len(f), f.agent.nunique())"
    futures = python("-c", read).stdout.split()
    assert futures == [str(2 * 20 * 12), "2"]  # 2 agents × K = 20 × 12 steps
