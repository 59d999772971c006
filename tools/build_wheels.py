"""Build fftool's two wheels into a folder: `fftool` (the code) and `fftool-models` (models/ and the profiles).

    python tools/build_wheels.py dist/
    pip install dist/fftool-*.whl dist/fftool_models-*.whl

Both are built from staged copies, so the checkout gets no build/ or egg-info folders; the models wheel takes
fftool's version. Needs setuptools in the running environment (no download: --no-build-isolation).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def version() -> str:
    found = re.search(r'__version__ = "([^"]+)"', (REPO / "src/fftool/__init__.py").read_text())
    assert found, "src/fftool/__init__.py names no __version__"
    return found[1]


def _wheel(source: Path, out: Path, name: str) -> Path:
    command = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(out)]
    subprocess.run([*command, str(source)], check=True)
    return out / f"{name}-{version()}-py3-none-any.whl"


def build(out: Path) -> list[Path]:
    """The paths of the two wheels, built into `out` (created if needed)."""
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        code = Path(tmp) / "fftool"
        code.mkdir()
        for name in ("pyproject.toml", "README.md"):
            shutil.copy2(REPO / name, code / name)
        shutil.copytree(REPO / "src", code / "src", ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        models = Path(tmp) / "fftool-models"
        shutil.copytree(REPO / "packaging/models", models, ignore=shutil.ignore_patterns("__pycache__"))
        pyproject = models / "pyproject.toml"
        pyproject.write_text(re.sub(r'(?m)^version = ".*"$', f'version = "{version()}"', pyproject.read_text()))
        shutil.copytree(REPO / "models", models / "fftool_models/models", ignore=shutil.ignore_patterns(".locks"))
        (models / "fftool_models/pipelines").mkdir()
        for profile in sorted((REPO / "pipelines").glob("*.toml")):
            shutil.copy2(profile, models / "fftool_models/pipelines" / profile.name)
        return [_wheel(code, out, "fftool"), _wheel(models, out, "fftool_models")]


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    for wheel in build(Path(sys.argv[1])):
        print(f"{wheel}  {wheel.stat().st_size / 1e6:.1f} MB")
