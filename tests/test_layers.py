"""Structure: leaf modules import nothing from fftool, stage modules never import each other."""

from __future__ import annotations

import ast
from pathlib import Path

import fftool

PACKAGE = Path(fftool.__file__).parent
LEAVES = {"errors", "scenes", "hashing", "ui", "groups"}
STAGE_MODULES = {"ingest", "windows", "forces", "maps", "goal", "goals", "cvae", "evaluate"}
ORCHESTRATION = {"pipeline", "cli", "ablation", "__main__"}


def _fftool_imports(module: str) -> set[str]:
    tree = ast.parse((PACKAGE / f"{module}.py").read_text())
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("fftool"):
            if node.module == "fftool":
                found.update(alias.name for alias in node.names)
            else:
                found.add(node.module.split(".")[1])
        elif isinstance(node, ast.Import):
            found.update(a.name.split(".")[1] for a in node.names if a.name.startswith("fftool."))
    return found - {"__init__"}


def test_leaves_import_nothing_from_fftool() -> None:
    for module in LEAVES:
        assert _fftool_imports(module) <= {"__version__"}, module


def test_stage_modules_do_not_import_each_other_or_the_orchestration() -> None:
    for module in STAGE_MODULES:
        imported = _fftool_imports(module)
        assert not imported & (STAGE_MODULES - {module}), f"{module} imports {imported & STAGE_MODULES}"
        assert not imported & ORCHESTRATION, module


def test_only_orchestration_imports_the_cli_or_pipeline() -> None:
    for path in PACKAGE.glob("*.py"):
        if path.stem not in ORCHESTRATION:
            assert not _fftool_imports(path.stem) & {"cli", "pipeline"}, path.stem


def test_the_force_math_depends_only_on_its_config() -> None:
    # socialforce.py is shared by the forces stage and the model: it must not reach into stages or I/O.
    assert _fftool_imports("socialforce") == {"config"}
