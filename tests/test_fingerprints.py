"""Fingerprints follow what each stage reads: a parameter changes a stage's fingerprint exactly when the
stage, or an upstream part it reads, depends on it (forces views included), for every stage and field."""

from __future__ import annotations

from pathlib import Path
from typing import Any, get_args

import numpy as np
import pytest
from pydantic import BaseModel, ValidationError

from fftool import pipeline
from fftool.artifacts.schema import FORCES_ARRAYS
from fftool.artifacts.store import ArtifactStore
from fftool.config import PipelineConfig, load_config, predictor_config
from fftool.learning.features import SAMPLING_READS, TRAINING_READS
from fftool.stages.forces import ARRAY_PARAMS

SCENES = Path(__file__).resolve().parents[2] / "shared" / "data" / "eth_ucy" / "scenes"
# Every cell of the DAG: (label, predictor for evaluate cells or None, protocol, target stage).
CELLS = [(stage, None, "paper", stage) for stage in ("tracks", "windows", "forces", "maps", "goal", "goals")]
CELLS += [(f"cvae[{v}]", v, "paper", "cvae") for v in ("baseline", "goal", "dr", "re")]
CELLS += [(f"evaluate[{p},{protocol}]", p, protocol, "evaluate")
          for p in ("cv", "baseline", "goal", "dr", "re") for protocol in ("paper", "oracle")]  # fmt: skip
# Fields that choose a cell rather than configure one, and paths (raw files, and a dataset TOML's description
# and files, enter by content hash: tests/test_custom_dataset.py checks that an edited file rebuilds).
NOT_PARAMETERS = {
    "cvae.variant", "evaluate.predictor", "evaluate.protocol", "data.raw_dir", "data.scenes_dir", "data.dataset",
}  # fmt: skip


def _perturbed(section: BaseModel, name: str) -> Any:
    """Another valid value of one field: halved / doubled numbers, another literal, a shorter tuple."""
    value = getattr(section, name)
    annotation = type(section).model_fields[name].annotation
    if isinstance(value, bool):
        candidates: list[Any] = [not value]
    elif isinstance(value, int):
        candidates = [value * 2 if value else 1, value + 1]
    elif isinstance(value, float):
        candidates = [value / 2 if value else 0.5, value * 1.5]
    elif isinstance(value, str) and not get_args(annotation):
        candidates = [value + "-changed"]
    elif isinstance(value, tuple):
        candidates = [value[:-1], value[1:]]
    else:
        candidates = [choice for choice in get_args(annotation) if choice != value]
    for candidate in candidates:
        try:
            type(section).model_validate(section.model_dump() | {name: candidate})
            return candidate
        except ValidationError:
            continue
    raise AssertionError(f"no valid perturbation of {type(section).__name__}.{name}")


def _fields(cfg: PipelineConfig) -> list[str]:
    return [
        f"{section}.{name}"
        for section in type(cfg).model_fields
        for name in type(getattr(cfg, section)).model_fields
        if f"{section}.{name}" not in NOT_PARAMETERS
    ]


def _with(cfg: PipelineConfig, dotted: str) -> PipelineConfig:
    section_name, name = dotted.split(".")
    section = getattr(cfg, section_name)
    changed = section.model_copy(update={name: _perturbed(section, name)})
    return cfg.model_copy(update={section_name: changed})


def _fingerprints(cfg: PipelineConfig) -> dict[str, str]:
    found = {}
    for label, predictor, protocol, target in CELLS:
        cell = cfg if predictor is None else predictor_config(cfg, predictor)
        cell = cell.model_copy(update={"evaluate": cell.evaluate.model_copy(update={"protocol": protocol})})
        found[label] = pipeline.resolve(cell, [target], "zara1")[-1].fingerprint
    return found


def _forces_fields(arrays: tuple[str, ...]) -> set[str]:
    return {f"forces.{name}" for array in arrays for name in ARRAY_PARAMS[array]}


def _expected(cfg: PipelineConfig) -> dict[str, set[str]]:
    """What each cell reads, written out: its own section and the sections (or force arrays) upstream."""

    def section(name: str, *unread: str) -> set[str]:
        return {f for f in _fields(cfg) if f.startswith(f"{name}.")} - {f"{name}.{u}" for u in unread}

    reads = {"tracks": section("ingest")}
    reads["windows"] = reads["tracks"] | section("windows")
    reads["forces"] = reads["windows"] | section("forces")
    reads["maps"] = section("maps")
    reads["goal"] = reads["windows"] | reads["maps"] | section("goal")
    reads["goals"] = reads["goal"] | section("goals")
    for v in ("baseline", "goal", "dr", "re"):
        reads[f"cvae[{v}]"] = reads["windows"] | section("cvae") | _forces_fields(TRAINING_READS[v])
    evaluate = section("evaluate", "protocol", "cv_angle_std_deg", "cv_speed_std")
    for protocol in ("paper", "oracle"):
        reads[f"evaluate[cv,{protocol}]"] = reads["windows"] | section("evaluate", "protocol")
        reads[f"evaluate[baseline,{protocol}]"] = reads["cvae[baseline]"] | evaluate
        for v in ("goal", "dr", "re"):
            goals = reads["goals"] if protocol != "oracle" else set()
            sampling = _forces_fields(SAMPLING_READS[v])
            reads[f"evaluate[{v},{protocol}]"] = reads[f"cvae[{v}]"] | goals | evaluate | sampling
    return reads


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> PipelineConfig:
    from tests.conftest import make_raw_tree

    raw = make_raw_tree(tmp_path_factory.mktemp("raw"))
    return load_config(None, [f"data.raw_dir={str(raw)!r}", f"data.scenes_dir={str(SCENES)!r}"])


def test_every_stage_is_fingerprinted_on_what_it_reads(base: PipelineConfig) -> None:
    before = _fingerprints(base)
    changed: dict[str, set[str]] = {label: set() for label in before}
    for dotted in _fields(base):
        after = _fingerprints(_with(base, dotted))
        for label in before:
            if after[label] != before[label]:
                changed[label].add(dotted)
    expected = _expected(base)
    for label in before:
        assert changed[label] == expected[label], (
            f"{label}: changes with {sorted(changed[label] - expected[label])} it does not read, "
            f"not with {sorted(expected[label] - changed[label])} it reads"
        )


def test_what_the_issue_named(base: PipelineConfig) -> None:
    """The field of view reaches only the repulsive force's consumers; force constants never reach the
    baseline, goal and constant-velocity cells."""
    before, after = _fingerprints(base), _fingerprints(_with(base, "forces.fov_deg"))
    moved = {label for label in before if before[label] != after[label]}
    assert moved == {"forces", "cvae[re]", "evaluate[re,paper]", "evaluate[re,oracle]"}
    for dotted in (f for f in _fields(base) if f.startswith("forces.")):
        after = _fingerprints(_with(base, dotted))
        for label in ("cvae[baseline]", "cvae[goal]", "evaluate[cv,paper]", "evaluate[baseline,paper]"):
            assert after[label] == before[label], (label, dotted)


def test_only_predictors_that_read_a_goal_depend_on_the_protocol(base: PipelineConfig) -> None:
    found = _fingerprints(base)
    for predictor in ("cv", "baseline", "goal", "dr", "re"):
        shared = found[f"evaluate[{predictor},paper]"] == found[f"evaluate[{predictor},oracle]"]
        assert shared == (predictor in ("cv", "baseline")), predictor


@pytest.fixture(scope="module")
def crowd(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A raw tree crowded enough for groups, close passes and partial tracks: walkers arrive one by one and
    the first leaves early (so a window's valid agents and its other present agents interleave)."""
    from tests.conftest import make_raw_tree

    root = make_raw_tree(tmp_path_factory.mktemp("crowd"), n_peds=10, n_frames=60, split_frame=40)
    for path in root.rglob("*.txt"):
        rows = [line.split("\t") for line in path.read_text().splitlines()]
        path.write_text("".join("\t".join(row) + "\n" for row in rows if not (row[1] == "1" and float(row[0]) >= 250)))
    return root


def _forces_arrays(raw: Path, root: Path, *overrides: str) -> dict[str, np.ndarray]:
    cfg = load_config(None, [f"data.raw_dir={str(raw)!r}", *overrides])
    forces = pipeline.run(cfg, ArtifactStore(root), ["forces"])["forces"]
    return {name: np.load(forces.file(file)) for name, file in FORCES_ARRAYS.items()}


@pytest.mark.parametrize("dotted", sorted(f"forces.{name}" for name in type(PipelineConfig().forces).model_fields))
def test_each_forces_array_depends_on_the_constants_its_view_names(dotted: str, crowd: Path, tmp_path: Path) -> None:
    """ARRAY_PARAMS, checked by computing: changing a constant changes exactly the arrays said to depend on it."""
    cfg = PipelineConfig()
    name = dotted.split(".")[1]
    # Values and settings under which each constant shows on a small crowd (e.g. v0 counts only when constant).
    strong = {"dbscan_eps_m": 3.0, "group_min_steps": 1, "desired_speed": "constant", "goal_min_distance_m": 1.0}
    context = {"desired_speed_mps": ["forces.desired_speed='constant'"],
               "neighbours": ["forces.dbscan_eps_m=3.0", "forces.group_min_steps=1"]}.get(name, [])  # fmt: skip
    value = strong.get(name, _perturbed(cfg.forces, name))
    before = _forces_arrays(crowd, tmp_path, *context)
    after = _forces_arrays(crowd, tmp_path, *context, f"{dotted}={value!r}")
    changed = {array for array in before if not np.array_equal(before[array], after[array])}
    assert changed == {array for array, params in ARRAY_PARAMS.items() if name in params}
