"""Structure: the package layers (docs/development.md) hold; each rule fails when one import breaks it."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import fftool

PACKAGE = Path(fftool.__file__).parent
MODULES = {
    ".".join(path.relative_to(PACKAGE).with_suffix("").parts).removesuffix("__init__").rstrip("."): path
    for path in PACKAGE.rglob("*.py")
}
LEAVES = {"errors", "ui", "paper", "variants", "dataset.scenes", "artifacts.hashing", "science.groups"}
STAGES = {name for name in MODULES if name.startswith("stages.") and name != "stages.contract"}
# Modules whose job needs no tensors: importing torch at their top would only slow every command down.
ENGINE = {"pipeline", "scheduler", "stages.contract"}
TORCH_FREE = (
    {"errors", "ui", "paper", "variants", "config", "cli", "science.groups"}
    | ENGINE
    | {name for name in MODULES if name.startswith(("dataset", "artifacts", "reporting.tables", "reporting.summaries"))}
)


def _imports(module: str, top_level_only: bool = False) -> set[str]:
    """fftool modules (dotted, without `fftool.`) and third-party roots that `module` imports."""
    tree = ast.parse(MODULES[module].read_text())
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    found = set()
    for node in nodes:
        if isinstance(node, ast.ImportFrom) and node.module:
            if node.module == "fftool":
                found.update(alias.name for alias in node.names)
            elif node.module.startswith("fftool."):
                name = node.module.removeprefix("fftool.")
                found.add(name)
                found.update(f"{name}.{a.name}" for a in node.names if f"{name}.{a.name}" in MODULES)
            else:
                found.add("ext:" + node.module.split(".")[0])
        elif isinstance(node, ast.Import):
            for alias in node.names:
                root = alias.name.removeprefix("fftool.") if alias.name.startswith("fftool.") else None
                found.add(root if root else "ext:" + alias.name.split(".")[0])
    return found - {"__version__"}


def _package(name: str) -> str:
    return name.split(".")[0]


def test_the_layout_is_the_documented_one() -> None:
    assert {_package(name) for name in MODULES} == {
        "",  # fftool/__init__.py
        "__main__", "errors", "ui", "outputs", "config", "paper", "variants", "pipeline", "scheduler",
        "api", "online", "zoo", "export", "exported",
        "artifacts", "dataset", "science", "models", "learning", "stages", "reporting", "cli",
    }  # fmt: skip
    assert {
        f"stages.{kind}"
        for kind in ("tracks", "windows", "forces", "maps", "goal", "goals", "cvae", "dlow", "evaluate")
    } == STAGES


@pytest.mark.parametrize("module", sorted(LEAVES))
def test_leaves_import_nothing_from_fftool(module: str) -> None:
    assert not {name for name in _imports(module) if not name.startswith("ext:")}, module


@pytest.mark.parametrize("module", sorted(name for name in MODULES if name.startswith("models")))
def test_models_import_nothing_of_fftool(module: str) -> None:
    assert {name for name in _imports(module) if not name.startswith("ext:")} <= {
        "models.forceformer",
        "models.goal_unet",
    }


@pytest.mark.parametrize("module", sorted(STAGES))
def test_a_stage_imports_no_other_stage_nor_the_layers_above(module: str) -> None:
    fftool_imports = {name for name in _imports(module) if not name.startswith("ext:")}
    assert not fftool_imports & (STAGES - {module}), f"{module} imports another stage"
    assert not {_package(name) for name in fftool_imports} & {"pipeline", "cli", "reporting"}, module
    assert "STAGE" in MODULES[module].read_text(), f"{module} does not declare its STAGE"


@pytest.mark.parametrize("module", sorted(name for name in MODULES if name.startswith("science")))
def test_the_science_reads_no_files(module: str) -> None:
    # forces, metrics, geometry: pure functions, shared by the stages and the models; no store, no I/O layers.
    packages = {_package(name) for name in _imports(module) if not name.startswith("ext:")}
    assert packages <= {"config", "errors", "science"}, f"{module} imports {packages}"


@pytest.mark.parametrize("module", sorted(name for name in MODULES if name.startswith(("learning", "artifacts"))))
def test_learning_and_artifacts_stay_below_the_stages(module: str) -> None:
    packages = {_package(name) for name in _imports(module) if not name.startswith("ext:")}
    assert not packages & {"stages", "pipeline", "reporting", "cli"}, f"{module} imports {packages}"


@pytest.mark.parametrize("module", sorted(TORCH_FREE & set(MODULES)))
def test_torch_free_modules_do_not_import_torch_at_the_top(module: str) -> None:
    assert "ext:torch" not in _imports(module, top_level_only=True), module


def test_only_the_top_layers_import_the_cli_or_the_engine() -> None:
    for module in MODULES:
        if _package(module) not in {"cli", "reporting", "__main__", "pipeline", "scheduler", "zoo"}:
            assert not {_package(name) for name in _imports(module)} & {"cli", "pipeline", "scheduler"}, module


@pytest.mark.parametrize("module", ["api", "online", "exported"])
def test_the_api_needs_no_cli_engine_nor_stage(module: str) -> None:
    # The API is for code that embeds the model: it reads artifacts and samples, never runs the pipeline.
    packages = {_package(name) for name in _imports(module) if not name.startswith("ext:")}
    assert not packages & {"cli", "pipeline", "scheduler", "stages", "reporting"}, packages
