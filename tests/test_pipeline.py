"""The DAG runner: cache skip on the second run, targeted rebuilds when parameters or bytes change."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from fftool import pipeline
from fftool.artifacts.store import ArtifactStore
from fftool.config import load_config, predictor_config, seeded_config
from fftool.errors import FftoolError


@pytest.fixture
def calls(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Spy on every stage's build function: records the stage names that were really built."""
    record: list[str] = []
    spied = {}
    for name, stage in pipeline.STAGES.items():

        def spy(cfg, inputs, ctx, _build=stage.build, _name=name):
            record.append(_name)
            return _build(cfg, inputs, ctx)

        spied[name] = dataclasses.replace(stage, build=spy)
    monkeypatch.setattr(pipeline, "STAGES", spied)
    return record


def _cfg(raw: Path, *overrides: str):
    return load_config(None, [f"data.raw_dir={str(raw)!r}", *overrides])


def test_second_run_builds_nothing(raw_tree: Path, store: ArtifactStore, calls: list[str]) -> None:
    first = pipeline.run(_cfg(raw_tree), store, ["windows"])
    assert calls == ["tracks", "windows"]
    second = pipeline.run(_cfg(raw_tree), store, ["windows"])
    assert calls == ["tracks", "windows"]
    assert {k: a.fingerprint for k, a in first.items()} == {k: a.fingerprint for k, a in second.items()}


def test_parameter_change_rebuilds_only_downstream(raw_tree: Path, store: ArtifactStore, calls: list[str]) -> None:
    pipeline.run(_cfg(raw_tree), store, ["windows"])
    pipeline.run(_cfg(raw_tree, "windows.window_stride=2"), store, ["windows"])
    assert calls == ["tracks", "windows", "windows"]
    assert len(store.list("windows")) == 2 and len(store.list("tracks")) == 1


def test_one_changed_input_byte_rebuilds_everything(raw_tree: Path, store: ArtifactStore, calls: list[str]) -> None:
    before = pipeline.run(_cfg(raw_tree), store, ["windows"])
    path = raw_tree / "all_data" / "biwi_eth.txt"
    text = path.read_text()
    path.write_text(text.replace("\t", " ", 1))  # same numbers, one different byte
    after = pipeline.run(_cfg(raw_tree), store, ["windows"])
    assert calls == ["tracks", "windows", "tracks", "windows"]
    assert before["tracks"].fingerprint != after["tracks"].fingerprint
    assert before["windows"].fingerprint != after["windows"].fingerprint


def test_force_rebuilds_the_named_stage(raw_tree: Path, store: ArtifactStore, calls: list[str]) -> None:
    pipeline.run(_cfg(raw_tree), store, ["windows"])
    pipeline.run(_cfg(raw_tree), store, ["windows"], force=["windows"])
    assert calls == ["tracks", "windows", "windows"]


def test_manifest_records_parameters_and_inputs(raw_tree: Path, store: ArtifactStore) -> None:
    built = pipeline.run(_cfg(raw_tree), store, ["windows"])
    tracks, windows = built["tracks"].manifest, built["windows"].manifest
    assert tracks.params == {"frame_stride": 10, "dt_s": 0.4, "duplicates": "warn"}
    assert len([k for k in tracks.inputs if k.startswith("raw/")]) == 24
    assert tracks.stats["frame_stride"] == 10 and tracks.stats["dt_s"] == 0.4
    assert windows.inputs == {"tracks": tracks.fingerprint}
    assert windows.params == {"obs_len": 8, "pred_len": 12, "window_stride": 1}


@pytest.mark.parametrize("profile", sorted(Path(__file__).resolve().parents[1].joinpath("pipelines").glob("*.toml")))
def test_every_shipped_profile_loads_and_plans_the_whole_dag(profile: Path) -> None:
    from fftool.reporting import ablation

    cfg = load_config(profile)
    for predictor in ablation.predictors(cfg, cfg.report.variants):
        cell = predictor_config(cfg, predictor)
        names = [item.stage.name for item in pipeline.resolve(cell, ["evaluate"], cfg.report.benchmarks[0])]
        assert names[-1] == "evaluate" and names[0] == "tracks"
        assert ("goals" in names) == (predictor in ("goal", "dr", "re"))


def test_a_missing_artifact_names_the_command_with_benchmark_and_variant(
    raw_tree: Path, built_store: ArtifactStore
) -> None:
    cfg = _cfg(raw_tree, "cvae.variant='dr'")
    assert not pipeline.run(cfg, built_store, ["forces"]).new  # the forces are built, the CVAE is not
    with pytest.raises(FftoolError, match=r"run `fftool train-cvae --benchmarks zara1 --variant dr` first"):
        pipeline.run(cfg, built_store, ["evaluate"], upstream=False, benchmark="zara1")


def test_a_grid_seed_changes_the_seeded_stages_and_nothing_upstream(raw_tree: Path) -> None:
    """`--seeds`: seed 0 keeps every fingerprint (the existing cells are grid seed 0); another seed changes
    the goal U-Net, its goal samples, the CVAE and the evaluation, never tracks, windows, forces or maps."""
    cfg = _cfg(raw_tree)

    def fingerprints(c, predictor: str) -> dict[str, str]:
        cell = predictor_config(c, predictor)
        return {r.stage.name: r.fingerprint for r in pipeline.resolve(cell, ["evaluate"], "zara1")}

    for predictor, seeded in (("re", {"goal", "goals", "cvae", "evaluate"}), ("cv", {"evaluate"})):
        base = fingerprints(cfg, predictor)
        assert fingerprints(seeded_config(cfg, 0), predictor) == base
        one, two = fingerprints(seeded_config(cfg, 1), predictor), fingerprints(seeded_config(cfg, 2), predictor)
        assert {name for name in base if one[name] != base[name]} == seeded
        assert {name for name in base if two[name] != one[name]} == seeded
        assert {"tracks", "windows"} <= set(base) - seeded
    assert {"forces", "maps"} <= set(fingerprints(cfg, "re")) - {"goal", "goals", "cvae", "evaluate"}
