"""Fingerprints follow what each stage declares it reads (STAGE.declare), and a build reads nothing else.

The expectations are derived from the declarations (a cell's fingerprint depends on its declared keys and,
through each upstream artifact it reads, on that artifact's keys or on the keys of the parts it reads); an
independent perturbation of every configuration field then measures which of the DAG's 24 cells change.
That builds read no undeclared key is enforced at run time (contract.ConfigView) and tested here too.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, get_args

import numpy as np
import pytest
from pydantic import BaseModel, ValidationError

from fftool import pipeline
from fftool.artifacts.schema import FORCES_ARRAYS
from fftool.artifacts.store import Artifact, ArtifactStore
from fftool.config import SECTIONS, PipelineConfig, load_config, predictor_config
from fftool.stages.contract import Reads, Stage, StageContext, UndeclaredRead, allowed_keys
from fftool.stages.forces import ARRAY_PARAMS
from fftool.stages.goal import VALIDATION_SAMPLING

SCENES = Path(__file__).resolve().parents[2] / "shared" / "data" / "eth_ucy" / "scenes"
# Every cell of the DAG: (label, predictor for evaluate cells or None, protocol, target stage).
CELLS = [(stage, None, "paper", stage) for stage in ("tracks", "windows", "forces", "maps", "goal", "goals")]
CELLS += [(f"cvae[{v}]", v, "paper", "cvae") for v in ("baseline", "goal", "dr", "re")]
CELLS += [(f"evaluate[{p},{protocol}]", p, protocol, "evaluate")
          for p in ("cv", "baseline", "goal", "dr", "re") for protocol in ("paper", "oracle")]  # fmt: skip
# The DLow sampler over a CVAE, and evaluations drawing through one ("+dlow": dlow.variants holds the variant).
CELLS += [("dlow[baseline]", "baseline", "paper", "dlow"), ("dlow[re]", "re", "paper", "dlow"),
          ("evaluate[baseline+dlow,paper]", "baseline+dlow", "paper", "evaluate"),
          ("evaluate[dr+dlow,paper]", "dr+dlow", "paper", "evaluate")]  # fmt: skip
# The fair protocol: each goal decoded from a prior draw or the DLow sampler's code (evaluate.fair_code "prior").
CELLS += [
    ("evaluate[goal,fair]", "goal", "fair", "evaluate"),
    ("evaluate[dr+dlow,fair]", "dr+dlow", "fair", "evaluate"),
]
# Goal variants trained with the goal module's errors ("+module": goal_training.source = "module").
CELLS += [("cvae[goal+module]", "goal+module", "paper", "cvae"), ("cvae[dr+module]", "dr+module", "paper", "cvae"),
          ("cvae[re+module]", "re+module", "paper", "cvae")]  # fmt: skip
# Fields that choose a cell rather than configure one (the variant, the predictor, the protocol, where goal
# variants' training goals come from and whether their best epoch is the fair one); the paths
# that say where raw files lie (Reads.locations) are left out as the declarations say.
SELECTORS = {
    "cvae.variant",
    "evaluate.predictor",
    "evaluate.protocol",
    "dlow.variants",
    "goal_training.source",
    "goal_training.fair_best_epoch",
}


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
    else:  # a literal, or a union such as int | "auto": its other literals, then small numbers
        candidates = [choice for choice in get_args(annotation) if choice != value] + [1, 2]
    for candidate in candidates:
        try:
            type(section).model_validate(section.model_dump() | {name: candidate})
            return candidate
        except ValidationError:
            continue
    raise AssertionError(f"no valid perturbation of {type(section).__name__}.{name}")


def _locations(cfg: PipelineConfig) -> set[str]:
    return {key for stage in pipeline.STAGES.values() for key in allowed_keys(cfg, stage.declare(cfg).locations)}


def _fields(cfg: PipelineConfig) -> list[str]:
    return [
        f"{section}.{name}"
        for section in SECTIONS
        for name in type(getattr(cfg, section)).model_fields
        if f"{section}.{name}" not in SELECTORS | _locations(cfg)
    ]


def _with(cfg: PipelineConfig, dotted: str) -> PipelineConfig:
    section_name, name = dotted.split(".")
    section = getattr(cfg, section_name)
    changed = section.model_copy(update={name: _perturbed(section, name)})
    return cfg.model_copy(update={section_name: changed})


def _cell(cfg: PipelineConfig, predictor: str | None, protocol: str) -> PipelineConfig:
    if predictor is not None and predictor.endswith("+module"):
        predictor = predictor.removesuffix("+module")
        cfg = cfg.model_copy(update={"goal_training": cfg.goal_training.model_copy(update={"source": "module"})})
    if predictor is not None and predictor.endswith("+dlow"):
        predictor = predictor.removesuffix("+dlow")
        cfg = cfg.model_copy(update={"dlow": cfg.dlow.model_copy(update={"variants": (predictor,)})})
    cell = cfg if predictor is None else predictor_config(cfg, predictor)
    return cell.model_copy(update={"evaluate": cell.evaluate.model_copy(update={"protocol": protocol})})


def _fingerprints(cfg: PipelineConfig) -> dict[str, str]:
    return {
        label: pipeline.resolve(_cell(cfg, predictor, protocol), [target], "zara1")[-1].fingerprint
        for label, predictor, protocol, target in CELLS
    }


def _declared(cfg: PipelineConfig, target: str) -> set[str]:
    """The keys `target`'s fingerprint depends on, by the declarations alone: its declared keys and, for each
    upstream artifact it reads, that artifact's keys (read whole) or the keys of the parts it reads together
    with what that artifact's own inputs depend on (a view hashes those too)."""
    items = {item.stage.name: item for item in pipeline.resolve(cfg, [target], "zara1")}

    def through_inputs(name: str) -> set[str]:
        found: set[str] = set()
        for upstream, parts in items[name].reads.artifacts.items():
            if parts is None:
                found |= keys(upstream)
            else:
                stage = items[upstream].stage
                found |= {f"{stage.section}.{key}" for key in stage.view_keys(parts)} | through_inputs(upstream)
        return found

    def keys(name: str) -> set[str]:
        return set(allowed_keys(cfg, items[name].reads.params)) | through_inputs(name)

    return keys(target) - SELECTORS


def _expected(cfg: PipelineConfig) -> dict[str, set[str]]:
    return {label: _declared(_cell(cfg, predictor, protocol), target) for label, predictor, protocol, target in CELLS}


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> PipelineConfig:
    from tests.conftest import make_raw_tree

    raw = make_raw_tree(tmp_path_factory.mktemp("raw"))
    return load_config(None, [f"data.raw_dir={str(raw)!r}", f"data.scenes_dir={str(SCENES)!r}"])


def test_every_stage_is_fingerprinted_on_what_it_declares(base: PipelineConfig) -> None:
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
            f"{label}: changes with {sorted(changed[label] - expected[label])} it does not declare, "
            f"not with {sorted(expected[label] - changed[label])} it declares"
        )


def test_the_declarations_say_what_the_stages_read(base: PipelineConfig) -> None:
    """A few facts of the declarations, written out, so that the derived expectations cannot drift unseen."""
    expected = _expected(base)
    assert set(VALIDATION_SAMPLING) <= expected["goal"]  # validation's goal sampling picks the goal model
    assert {"goals.seed", "goals.parts", "goals.cv_angle_std_deg"}.isdisjoint(expected["goal"])
    assert not any(key.startswith("forces.") for key in expected["cvae[baseline]"] | expected["cvae[goal]"])
    assert "forces.fov_deg" in expected["cvae[re]"] and "forces.fov_deg" not in expected["cvae[dr]"]
    assert "evaluate.cv_angle_std_deg" in expected["evaluate[cv,paper]"]
    assert "evaluate.cv_angle_std_deg" not in expected["evaluate[dr,paper]"]
    assert not any(key.startswith("dlow.") for key in expected["evaluate[dr,paper]"])
    assert "dlow.lr" in expected["evaluate[dr+dlow,paper]"] and "dlow.variants" not in expected["dlow[re]"]
    assert "cvae.lr" in expected["dlow[re]"] and "forces.fov_deg" in expected["dlow[re]"]


@pytest.mark.parametrize("dotted", VALIDATION_SAMPLING)
def test_the_goal_model_is_fingerprinted_on_the_sampling_its_validation_uses(base: PipelineConfig, dotted: str) -> None:
    """train-goal keeps the epoch with the best validation goal-FDE@K, drawn with these goals settings: a
    goal model selected under other settings must not be reused (the bug of issue 24)."""
    fp = lambda cfg: pipeline.resolve(cfg, ["goal"], "zara1")[-1].fingerprint  # noqa: E731
    assert fp(_with(base, dotted)) != fp(base)


def test_what_the_issue_named(base: PipelineConfig) -> None:
    """The field of view reaches only the repulsive force's consumers; force constants never reach the
    baseline, goal and constant-velocity cells."""
    before, after = _fingerprints(base), _fingerprints(_with(base, "forces.fov_deg"))
    moved = {label for label in before if before[label] != after[label]}
    assert moved == {"forces", "cvae[re]", "evaluate[re,paper]", "evaluate[re,oracle]", "dlow[re]", "cvae[re+module]"}
    for dotted in (f for f in _fields(base) if f.startswith("forces.")):
        after = _fingerprints(_with(base, dotted))
        for label in (
            "cvae[baseline]",
            "cvae[goal]",
            "evaluate[cv,paper]",
            "evaluate[baseline,paper]",
            "dlow[baseline]",
        ):
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


def _speeds(cfg: Any, inputs: Mapping[str, Artifact], ctx: StageContext) -> dict[str, Any]:
    """A stage that declares windows.obs_len but also reads windows.pred_len."""
    return {"steps": cfg.windows.obs_len + cfg.windows.pred_len}


def test_a_build_that_reads_an_undeclared_key_fails_and_leaves_nothing(
    base: PipelineConfig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    declare = lambda cfg: Reads(params=("windows.obs_len",), artifacts={"windows": None})  # noqa: E731
    stage = Stage("speeds", 1, "fftool speeds", "speeds", declare, _speeds)
    monkeypatch.setitem(pipeline.STAGES, "speeds", stage)
    store = ArtifactStore(tmp_path)
    with pytest.raises(UndeclaredRead, match=r"'speeds' read windows\.pred_len, which its declaration"):
        pipeline.run(base, store, ["speeds"])
    assert not (tmp_path / "speeds").exists() and not list(tmp_path.glob(".incomplete/*"))
    assert store.lookup("windows", pipeline.resolve(base, ["windows"])[-1].fingerprint) is not None
    # declared, the same build runs, and the key it declared enters its fingerprint
    both = ("windows.obs_len", "windows.pred_len")
    declared = Stage("speeds", 1, "fftool speeds", "speeds", lambda cfg: Reads(both, {"windows": None}), _speeds)
    monkeypatch.setitem(pipeline.STAGES, "speeds", declared)
    assert pipeline.run(base, store, ["speeds"])["speeds"].manifest.stats["steps"] == 20
    assert pipeline.resolve(base, ["speeds"])[-1].params == {"windows.obs_len": 8, "windows.pred_len": 12}


def test_the_view_hands_whole_sections_parts_of_sections_and_nothing_else(base: PipelineConfig) -> None:
    item = pipeline.resolve(predictor_config(base, "dr"), ["cvae"], "zara1")[-1]
    view = item.config_view(base)
    assert view.cvae is base.cvae  # declared whole: the section itself
    assert view.forces.tau_s == base.forces.tau_s  # read through the forces[f_dr, speed0] view
    assert set(view.forces.model_dump()) == ARRAY_PARAMS["f_dr"] | ARRAY_PARAMS["speed0"]
    with pytest.raises(UndeclaredRead, match=r"forces\.fov_deg"):
        _ = view.forces.fov_deg  # the repulsive force's constant: dr does not read it
    with pytest.raises(UndeclaredRead, match=r"goal\.epochs"):
        _ = view.goal.epochs


def test_a_variants_recipe_moves_that_variants_cells_alone_to_the_fingerprints_of_its_values(
    base: PipelineConfig,
) -> None:
    """`[per_variant.baseline.cvae]` retrains the baseline (and what draws from it) and nothing else, and the
    baseline's fingerprints are those of the same values set for every variant: one model, however asked for."""
    everywhere = _with(base, "cvae.best_of_k_warmup_epochs")
    warmup = everywhere.cvae.best_of_k_warmup_epochs
    recipe = {"per_variant": {"baseline": {"cvae": {"best_of_k_warmup_epochs": warmup}}}}
    before, after = _fingerprints(base), _fingerprints(PipelineConfig.model_validate(base.model_dump() | recipe))
    same_values = _fingerprints(everywhere)
    moved = {label for label in before if after[label] != before[label]}
    assert moved == {"cvae[baseline]", "dlow[baseline]", "evaluate[baseline,paper]", "evaluate[baseline,oracle]",
                     "evaluate[baseline+dlow,paper]"}  # fmt: skip
    assert all(after[label] == same_values[label] for label in moved)
