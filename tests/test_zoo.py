"""The model zoo: shipped models stay current with the code, install only intact files under the fingerprints the
code computes, load by name, and `reproduce` then trains nothing."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from typer.testing import CliRunner

from fftool import api, pipeline, zoo
from fftool.artifacts.hashing import fingerprint
from fftool.artifacts.store import ArtifactStore
from fftool.cli import app
from fftool.config import load_config, predictor_config
from fftool.errors import FftoolError, IntegrityError
from fftool.learning import goal_model
from fftool.learning.fair_validation import fair_validation
from fftool.online import OnlinePredictor
from fftool.reporting.summaries import zoo_rows
from tests.test_maps import make_scene
from tests.test_reproduce import TINY_PIPELINE

# --- the models in the repository -------------------------------------------------------------------------


def test_the_shipped_models_are_current_and_intact() -> None:
    """Fails whenever a code change would orphan a shipped model: the message says to retrain or re-key it."""
    profiles = zoo.profiles()
    assert "cpu" in profiles, f"no shipped cpu models under {zoo.models_root()}"
    for profile in profiles:
        models = zoo.shipped(profile)
        assert models, f"models/{profile} ships nothing"
        stale = zoo.orphans(models)
        assert not stale, "\n".join(stale.values())
        shipped_store = zoo.store(profile)
        for model in models:
            zoo.check(model, shipped_store)  # every file's sha256 against its manifest, and the schema version


def test_a_changed_stage_version_orphans_the_shipped_models(monkeypatch: pytest.MonkeyPatch) -> None:
    models = zoo.shipped("cpu")
    cvae_stage = pipeline.STAGES["cvae"]
    monkeypatch.setitem(pipeline.STAGES, "cvae", dataclasses.replace(cvae_stage, version=cvae_stage.version + 1))
    stale = zoo.orphans(models)
    expected = {m.name for m in models if m.kind in ("cvae", "dlow")}  # a DLow sampler keys on its CVAE
    assert set(stale) == expected and expected
    assert all("Retrain it" in line and "re-key it" in line for line in stale.values())
    assert not any(m.name in stale for m in models if m.kind == "goal")


# --- pack, list, install, load: a tiny profile ---------------------------------------------------------------


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A tiny profile trained once for the module (goal U-Net, baseline and dr CVAEs, the baseline's DLow
    sampler): its pipelines folder and its store."""
    from tests.conftest import make_raw_tree

    base = tmp_path_factory.mktemp("zoo")
    raw = make_raw_tree(base / "raw")
    make_scene(base / "scenes" / "zara1")
    pipelines = base / "pipelines"
    pipelines.mkdir()
    text = TINY_PIPELINE.format(raw=str(raw), scenes=str(base / "scenes"))
    text = text.replace("[goal]\n", "[goal]\nneighbour_channels = true\n")  # as the shipped cpu goal U-Nets
    (pipelines / "tiny.toml").write_text(text.replace("[dlow]\n", '[dlow]\nvariants = ["baseline"]\n'))
    store = ArtifactStore(base / "trained")
    cfg = load_config(pipelines / "tiny.toml")
    for kind, variant in (("goal", None), ("cvae", "baseline"), ("cvae", "dr"), ("dlow", "baseline")):
        pipeline.run(cfg if variant is None else predictor_config(cfg, variant), store, [kind], benchmark="zara1")
    return pipelines, store.root


@pytest.fixture
def tiny(trained: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Path]:
    """The trained tiny profile with a pipelines folder and an empty zoo of this test's own."""
    pipelines = tmp_path / "pipelines"
    shutil.copytree(trained[0], pipelines)  # a test may edit the profile
    monkeypatch.setattr(zoo, "pipelines_root", lambda: pipelines)
    monkeypatch.setenv(zoo.ENV_MODELS, str(tmp_path / "models"))
    return {"trained": trained[1], "pipelines": pipelines, "models": tmp_path / "models", "tmp": tmp_path}


def _cli(*args: object) -> str:
    result = CliRunner().invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result.output


def test_pack_list_install_then_nothing_is_trained(tiny: dict[str, Path]) -> None:
    _cli("models", "pack", "--profile", "tiny", "--benchmarks", "zara1", "--root", tiny["trained"])
    names = {m.name for m in zoo.shipped("tiny")}
    assert names == {"tiny/zara1/goal-unet", "tiny/zara1/baseline", "tiny/zara1/dr", "tiny/zara1/baseline/dlow"}
    listing = _cli("models", "list", "--profile", "tiny")
    assert "tiny/zara1/dr" in listing and "current" in listing
    fresh = tiny["tmp"] / "fresh"
    assert "4 model(s) installed" in _cli("models", "install", "--profile", "tiny", "--root", fresh)
    assert "0 model(s) installed, 4 already" in _cli("models", "install", "--profile", "tiny", "--root", fresh)
    cfg = load_config(tiny["pipelines"] / "tiny.toml")
    for variant in ("baseline", "dr"):
        built = pipeline.run(predictor_config(cfg, variant), ArtifactStore(fresh), ["cvae"], benchmark="zara1")
        assert "cvae" not in built.new  # found, not trained: the model that was packed
        assert ArtifactStore(tiny["trained"]).lookup("cvae", built["cvae"].fingerprint) is not None
    built = pipeline.run(predictor_config(cfg, "baseline"), ArtifactStore(fresh), ["dlow"], benchmark="zara1")
    assert "dlow" not in built.new
    assert "goal" not in pipeline.run(cfg, ArtifactStore(fresh), ["goal"], benchmark="zara1").new


def test_a_shipped_name_loads_the_model_its_profile_evaluates(tiny: dict[str, Path]) -> None:
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    store = ArtifactStore(tiny["trained"])
    cfg = predictor_config(load_config(tiny["pipelines"] / "tiny.toml"), "baseline")
    ids = {kind: pipeline.resolve(cfg, [kind], "zara1")[-1].fingerprint[:16] for kind in ("cvae", "dlow")}
    past = np.cumsum(np.full((1, 2, 8, 2), 0.4), axis=2)
    by_name = api.load("tiny/zara1/baseline").predict(past, np.ones((1, 2), bool), k=20, seed=3)
    by_id = api.load(f"cvae/{ids['cvae']}", root=store.root, dlow=f"dlow/{ids['dlow']}")
    assert np.array_equal(by_name, by_id.predict(past, np.ones((1, 2), bool), k=20, seed=3))
    assert api.load("tiny/zara1/baseline").sampler is not None and api.load("tiny/zara1/dr").sampler is None
    assert api.load_goal_sampler("tiny/zara1/dr") is not None
    with pytest.raises(FftoolError, match="no shipped model tiny/zara1/re"):
        api.load("tiny/zara1/re")


def test_install_refuses_a_damaged_or_swapped_file_and_copies_nothing(tiny: dict[str, Path]) -> None:
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    models = {m.name: m for m in zoo.shipped("tiny")}
    dr, baseline = models["tiny/zara1/dr"].artifact, models["tiny/zara1/baseline"].artifact
    original = (dr.path / "model.pt").read_bytes()
    shutil.copyfile(baseline.path / "model.pt", dr.path / "model.pt")  # another model's weights, same name
    fresh = tiny["tmp"] / "fresh"
    result = CliRunner().invoke(app, ["models", "install", "--profile", "tiny", "--root", str(fresh)])
    assert result.exit_code == 1 and "model.pt: content changed" in result.output
    assert len(result.output.strip().splitlines()) == 1 and "Traceback" not in result.output
    assert not fresh.exists() or not ArtifactStore(fresh).list()
    with pytest.raises(IntegrityError, match="damaged"):
        api.load("tiny/zara1/dr")
    (dr.path / "model.pt").write_bytes(original[:-100])  # truncated
    with pytest.raises(IntegrityError, match=r"model\.pt"):
        zoo.install(ArtifactStore(fresh), zoo.shipped("tiny"))


def test_a_profile_change_orphans_the_models_and_rekey_refuses_other_parameters(tiny: dict[str, Path]) -> None:
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    profile = tiny["pipelines"] / "tiny.toml"
    profile.write_text(profile.read_text().replace("train_k = 2", "train_k = 3"))
    stale = zoo.orphans(zoo.shipped("tiny"))
    assert set(stale) == {"tiny/zara1/baseline", "tiny/zara1/dr", "tiny/zara1/baseline/dlow"}
    result = CliRunner().invoke(app, ["models", "install", "--profile", "tiny", "--root", str(tiny["tmp"] / "x")])
    assert result.exit_code == 1 and "Retrain it" in result.output
    with pytest.raises(FftoolError, match="trained with other parameters \\(train_k\\); retrain it"):
        zoo.rekey("tiny")


def test_a_pack_drops_the_models_its_profile_no_longer_trains(tiny: dict[str, Path]) -> None:
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    sampler = next(m for m in zoo.shipped("tiny") if m.name == "tiny/zara1/baseline/dlow")
    profile = tiny["pipelines"] / "tiny.toml"
    profile.write_text(profile.read_text().replace('variants = ["baseline"]', "variants = []"))  # no sampler now
    packed = zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    assert "tiny/zara1/baseline/dlow" not in packed
    assert {m.name for m in zoo.shipped("tiny")} == {"tiny/zara1/goal-unet", "tiny/zara1/baseline", "tiny/zara1/dr"}
    assert not sampler.artifact.path.exists() and not zoo.orphans(zoo.shipped("tiny"))


def test_a_failed_pack_leaves_no_models_folder(tiny: dict[str, Path]) -> None:
    with pytest.raises(FftoolError, match="has no goal model of zara1"):
        zoo.pack(ArtifactStore(tiny["tmp"] / "empty"), "tiny", ["zara1"])
    assert not tiny["models"].exists()


def test_rekey_refuses_models_whose_training_inputs_changed_upstream(
    tiny: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Windows of 10 observed steps instead of 8 change no model's own parameters, only its upstream
    fingerprints, as a code change would: the lineage packed with each model tells the two apart."""
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    assert all("lineage" in m.artifact.manifest.stats for m in zoo.shipped("tiny"))
    profile = tiny["pipelines"] / "tiny.toml"
    profile.write_text(profile.read_text() + "\n[windows]\nobs_len = 10\n")
    assert len(zoo.orphans(zoo.shipped("tiny"))) == 4
    with pytest.raises(FftoolError, match=r"trained with other parameters \(windows\.obs_len\); retrain it"):
        zoo.rekey("tiny")


def test_rekey_gives_a_current_model_without_a_lineage_its_own(tiny: dict[str, Path]) -> None:
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    model = zoo.shipped("tiny")[0].artifact
    manifest = json.loads((model.path / "manifest.json").read_text())
    recorded = manifest["stats"].pop("lineage")
    (model.path / "manifest.json").write_text(json.dumps(manifest))
    zoo.write_index(ArtifactStore(tiny["models"] / "tiny"))  # as an fftool without lineages packed it
    assert zoo.rekey("tiny") == []  # nothing moved
    assert zoo.shipped("tiny")[0].artifact.manifest.stats["lineage"] == recorded


def test_rekey_moves_models_whose_code_version_alone_changed(
    tiny: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    windows_stage = pipeline.STAGES["windows"]  # upstream of everything: every fingerprint moves, no parameter
    monkeypatch.setitem(
        pipeline.STAGES, "windows", dataclasses.replace(windows_stage, version=windows_stage.version + 1)
    )
    assert len(zoo.orphans(zoo.shipped("tiny"))) == 4
    assert len(zoo.rekey("tiny")) == 4
    assert not zoo.orphans(zoo.shipped("tiny"))
    moved = zoo.shipped("tiny")[0].artifact.manifest
    assert "rekeyed_from" in moved.stats


def test_rekey_moves_a_model_trained_before_an_option_existed_when_the_profile_leaves_it_at_its_default(
    tiny: dict[str, Path],
) -> None:
    """A shipped goal U-Net whose manifest lacks `scene_prior` (written before the option existed) is orphaned;
    re-keyed, since the profile keeps the default, the behaviour it was trained with; refused once it does not."""
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    unet = next(m for m in zoo.shipped("tiny") if m.kind == "goal").artifact
    manifest = json.loads((unet.path / "manifest.json").read_text())
    del manifest["params"]["scene_prior"]
    manifest["fingerprint"] = fingerprint(
        "goal", pipeline.STAGES["goal"].version, manifest["params"], manifest["inputs"]
    )
    older = unet.path.with_name(manifest["fingerprint"][:16])
    unet.path.rename(older)
    (older / "manifest.json").write_text(json.dumps(manifest))
    zoo.write_index(ArtifactStore(tiny["models"] / "tiny"))  # as the older fftool packed it
    assert list(zoo.orphans(zoo.shipped("tiny"))) == ["tiny/zara1/goal-unet"]
    profile = tiny["pipelines"] / "tiny.toml"
    text = profile.read_text()
    profile.write_text(text.replace("[goal]\n", '[goal]\nscene_prior = "occupancy"\n'))
    with pytest.raises(FftoolError, match="trained with other parameters \\(scene_prior\\)"):
        zoo.rekey("tiny")
    profile.write_text(text)
    assert zoo.rekey("tiny") == ["tiny/zara1/goal-unet"]
    assert not zoo.orphans(zoo.shipped("tiny"))


def _record_goal_unet_with(tiny: dict[str, Path], key: str, value: object) -> None:
    """Rewrite the shipped goal U-Net as an older fftool would have packed it, with `key` among its params."""
    unet = next(m for m in zoo.shipped("tiny") if m.kind == "goal").artifact
    manifest = json.loads((unet.path / "manifest.json").read_text())
    manifest["params"][key] = value
    manifest["fingerprint"] = fingerprint(
        "goal", pipeline.STAGES["goal"].version, manifest["params"], manifest["inputs"]
    )
    older = unet.path.with_name(manifest["fingerprint"][:16])
    unet.path.rename(older)
    (older / "manifest.json").write_text(json.dumps(manifest))
    zoo.write_index(ArtifactStore(tiny["models"] / "tiny"))


@pytest.mark.parametrize(("recorded", "moved"), [("kept", True), ("rejected", False)])
def test_rekey_moves_a_model_recorded_with_a_retired_option_only_at_the_behaviour_kept(
    tiny: dict[str, Path], monkeypatch: pytest.MonkeyPatch, recorded: str, moved: bool
) -> None:
    """An option removed from the code (`zoo.RETIRED`) leaves one behaviour: a model recorded with it was trained
    as today's code trains and is re-keyed; one recorded with the rejected value is refused."""
    monkeypatch.setitem(zoo.RETIRED, "goal.old_option", "kept")
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    _record_goal_unet_with(tiny, "old_option", recorded)
    assert list(zoo.orphans(zoo.shipped("tiny"))) == ["tiny/zara1/goal-unet"]
    if moved:
        assert zoo.rekey("tiny") == ["tiny/zara1/goal-unet"] and not zoo.orphans(zoo.shipped("tiny"))
    else:
        with pytest.raises(FftoolError, match="trained with other parameters \\(old_option\\)"):
            zoo.rekey("tiny")


def test_models_validate_shows_goal_variants_under_the_fair_protocol(tiny: dict[str, Path]) -> None:
    """`models list` labels a true-goal-trained dr's numbers "true goals" until `models validate` scores it the
    way predictions are made (sample k decodes goal k of the shipped goal U-Net); then it shows those, "fair"."""
    source = tiny["tmp"] / "store"
    shutil.copytree(tiny["trained"], source, ignore=shutil.ignore_patterns(".locks"))
    zoo.pack(ArtifactStore(source), "tiny", ["zara1"])
    assert "(true goals)" in _cli("models", "list", "--profile", "tiny")
    with pytest.raises(FftoolError, match="fftool sample-goals --benchmarks zara1"):
        zoo.validate(ArtifactStore(source), "tiny", ["zara1"])
    cfg = load_config(tiny["pipelines"] / "tiny.toml")
    goals = pipeline.run(cfg, ArtifactStore(source), ["goals"], benchmark="zara1")["goals"]
    out = _cli("models", "validate", "--profile", "tiny", "--benchmarks", "zara1", "--root", source)
    assert "scored 1 model(s) under the fair protocol: tiny/zara1/dr" in out
    dr = next(m for m in zoo.shipped("tiny") if m.name == "tiny/zara1/dr")
    scored = dr.artifact.manifest.stats["fair_validation"]
    unet = next(m for m in zoo.shipped("tiny") if m.kind == "goal")
    assert scored["goal_unet"] == unet.artifact.fingerprint and scored["k"] == 20
    true_goals = summaries_best(dr)
    assert (scored["min_ade_m"], scored["min_fde_m"]) != true_goals  # another protocol, another number
    rows = {row["name"]: row for row in zoo_rows(zoo.shipped("tiny"))}
    assert rows["tiny/zara1/dr"]["validation (best epoch)"] == (
        f"minADE/FDE {scored['min_ade_m']:.3f}/{scored['min_fde_m']:.3f} (fair)"
    )
    assert "(fair)" in _cli("models", "list", "--profile", "tiny")
    assert not zoo.orphans(zoo.shipped("tiny"))  # the manifest's stats changed, never its fingerprint
    # each benchmark reads the whole zoo, which must stay whole after the one before was scored
    assert zoo.validate(ArtifactStore(source), "tiny", ["zara1", "zara1"]) == ["tiny/zara1/dr"] * 2
    assert goals.id in {a.id for a in ArtifactStore(source).list("goals")}


def test_fair_validation_scores_a_chosen_number_of_windows_and_a_scaled_residual(tiny: dict[str, Path]) -> None:
    """`windows` draws the subset as training does, with the CVAE's seed: its own count reproduces the model's own
    fair validation, and more windows score more (every model of a benchmark and seed on the same ones).
    `residual_scale` scales the whole learned output: at 0 only the path it is a residual over is left."""
    source = tiny["tmp"] / "store"
    shutil.copytree(tiny["trained"], source, ignore=shutil.ignore_patterns(".locks"))
    store = ArtifactStore(source)
    goals = pipeline.run(load_config(tiny["pipelines"] / "tiny.toml"), store, ["goals"], benchmark="zara1")["goals"]
    (cvae,) = (a for a in store.list("cvae") if a.manifest.stats["variant"] == "dr")
    own = fair_validation(store, goals, cvae, None, torch.device("cpu"), "mean")
    same = fair_validation(store, goals, cvae, None, torch.device("cpu"), "mean", windows=own["windows"])
    assert same == own
    more = fair_validation(store, goals, cvae, None, torch.device("cpu"), "mean", windows=own["windows"] + 2)
    assert more["windows"] == own["windows"] + 2 and more["min_ade_m"] != own["min_ade_m"]
    # residual_scale 0 leaves only the path the output is a residual over (here "offset": standing still), which
    # no code and no other model's weights can move
    curve = fair_validation(store, goals, cvae, None, torch.device("cpu"), "mean", residual_scale=0.0)
    drawn = fair_validation(store, goals, cvae, None, torch.device("cpu"), "prior", residual_scale=0.0)
    (baseline,) = (a for a in store.list("cvae") if a.manifest.stats["variant"] == "baseline")
    other = fair_validation(store, goals, baseline, None, torch.device("cpu"), "prior", residual_scale=0.0)
    assert curve["min_ade_m"] == drawn["min_ade_m"] == other["min_ade_m"] != own["min_ade_m"]
    halfway = fair_validation(store, goals, cvae, None, torch.device("cpu"), "mean", residual_scale=0.5)
    assert halfway["min_ade_m"] not in (own["min_ade_m"], curve["min_ade_m"])


def summaries_best(model: zoo.Shipped) -> tuple[float, float]:
    stats = model.artifact.manifest.stats
    row = next(r for r in stats["log"] if r["epoch"] == stats["best_epoch"])
    return (
        next(v for k, v in row.items() if k.startswith("val_min_ade")),
        next(v for k, v in row.items() if k.startswith("val_min_fde")),
    )


def test_passed_goals_come_before_a_shipped_goal_unet_however_the_predictor_was_made(tiny: dict[str, Path]) -> None:
    """A planner's goals steer the agents it names, by name or from a loaded model; the others get sampled goals."""
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    by_name = OnlinePredictor("tiny/zara1/dr", k=5, seed=1)
    loaded = OnlinePredictor(api.load("tiny/zara1/dr"), goal_sampler="tiny/zara1/dr", k=5, seed=1)
    passed = {1: (9.0, -4.0)}
    for online in (by_name, loaded):
        for step in range(8):
            result = online.update(0.4 * step, {1: (0.4 * step, 0.0), 2: (0.0, 0.3 * step)}, goals=passed)
        assert result.agents.tolist() == [1, 2]
        assert np.allclose(result.goals[0], [9.0, -4.0])  # every sample of agent 1 heads to the passed goal
        assert not np.allclose(result.goals[1], result.goals[1][0])  # agent 2: K goals from the U-Net
    assert np.array_equal(by_name.update(3.2, {1: (3.2, 0.0)}, goals=passed).goals[0], np.tile([9.0, -4.0], (5, 1)))


def test_a_goal_unet_reading_the_other_walkers_reads_only_its_own_scenes(tiny: dict[str, Path]) -> None:
    """Predicting several scenes at once (`predict --at all`), each agent's goal map reads the other walkers of its
    own scene: the maps are those of each scene alone, and not those of everyone taken as one scene."""
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    sampler = api.load_goal_sampler("tiny/zara1/dr")
    assert sampler.config.neighbour_channels
    rng = np.random.default_rng(3)
    past = np.cumsum(rng.normal(0.3, 0.1, (5, 8, 2)), 1) + rng.normal(0, 1.5, (5, 1, 2))
    window = np.array([0, 0, 1, 1, 1])
    others = goal_model.Neighbours.of(past, window).observed(slice(None), 8)
    xy = torch.as_tensor(past, dtype=torch.float32)
    together = sampler.maps(xy, 12, others)[0]
    alone = torch.cat([sampler.maps(xy[torch.as_tensor(window == w)], 12)[0] for w in (0, 1)])
    torch.testing.assert_close(together, alone, atol=1e-5, rtol=0)
    assert (sampler.maps(xy, 12)[0] - together).abs().max() > 1e-4  # one scene of five reads other walkers
    goals = sampler.sample(past, 4, 0, 12, torch.device("cpu"), window)
    first = sampler.sample(past[:2], 4, 0, 12, torch.device("cpu"))
    np.testing.assert_allclose(goals[:2, 0], first[:, 0], atol=1e-5)  # the mode: no draw involved


def test_predict_the_api_and_the_online_predictor_read_no_future_position(tiny: dict[str, Path]) -> None:
    """The fair path users take: a shipped goal variant predicting at time t gives the same futures whether the
    tracks after t are there, scrambled or gone; the online predictor, fed up to t, gives the same again (to
    float rounding: it decodes the most-likely future in the same rollout, one more window per batch)."""
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    rng = np.random.default_rng(0)
    times = np.arange(20) * 0.4
    tracks = pd.DataFrame(
        [(t, agent, x0 + 0.4 * i, y0 + 0.1 * i) for agent, (x0, y0) in enumerate([(0, 0), (5, 2)]) for i, t in
         enumerate(times)], columns=["time_s", "agent", "x", "y"])  # fmt: skip
    at, model = float(times[9]), api.load("tiny/zara1/dr")
    sampler = api.load_goal_sampler("tiny/zara1/dr")
    future = tracks["time_s"] > at + 1e-9
    scrambled = tracks.copy()
    scrambled.loc[future, ["x", "y"]] = rng.normal(0, 50, (int(future.sum()), 2))
    tables = [
        api.predict_tracks(model, frame, at=[at], k=5, seed=2, goal_sampler=sampler)[0]
        for frame in (tracks, scrambled, tracks[~future])
    ]
    assert len(tables[0]) == 2 * 5 * 12 and not tables[0].isna().any().any()
    for table in tables[1:]:
        pd.testing.assert_frame_equal(table, tables[0])
    online = OnlinePredictor("tiny/zara1/dr", k=5, seed=2)
    for t, rows in tracks[~future].groupby("time_s"):
        result = online.update(float(t), dict(zip(rows["agent"], zip(rows["x"], rows["y"]))))
    np.testing.assert_allclose(
        result.table()[["x", "y"]].to_numpy(), tables[0][["x", "y"]].to_numpy(), rtol=0, atol=1e-5
    )


def _dlow_folder(tiny: dict[str, Path]) -> Path:
    return next(m for m in zoo.shipped("tiny") if m.kind == "dlow").artifact.path


@pytest.mark.parametrize(
    "spoil",
    ["truncate the sampler's manifest", "edit stats.variant", "plant a second baseline", "remove the sampler",
     "link loop inside"],
)  # fmt: skip
def test_a_damaged_edited_planted_or_missing_model_is_an_error_wherever_the_zoo_is_read(
    tiny: dict[str, Path], spoil: str
) -> None:
    """Each of these once let `predict` draw from another model (the prior instead of the sampler), or let
    `models list` show one model fewer and `install` report success."""
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    folder = _dlow_folder(tiny)
    manifest = folder / "manifest.json"
    if spoil == "truncate the sampler's manifest":
        manifest.write_text(manifest.read_text()[:100])
    elif spoil == "edit stats.variant":
        data = json.loads(manifest.read_text())
        data["stats"]["variant"] = "dr"
        manifest.write_text(json.dumps(data))
    elif spoil == "plant a second baseline":
        cvae = next(m for m in zoo.shipped("tiny") if m.name == "tiny/zara1/baseline").artifact.path
        shutil.copytree(cvae, cvae.with_name("0" * 16))
    elif spoil == "remove the sampler":
        shutil.rmtree(folder)
    else:
        (folder / "loop").symlink_to(folder, target_is_directory=True)
    for read in (
        lambda: _cli("models", "list", "--profile", "tiny"),
        lambda: zoo.install(ArtifactStore(tiny["tmp"] / "fresh"), zoo.shipped("tiny")),
        lambda: api.load("tiny/zara1/baseline"),
    ):
        with pytest.raises((IntegrityError, AssertionError)) as caught:
            read()
        assert "Traceback" not in str(caught.value) and "[" not in str(caught.value).split(":")[0]
    assert not (tiny["tmp"] / "fresh" / "dlow").exists()


def test_an_empty_or_missing_models_folder_is_named(tiny: dict[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    for folder in (tiny["tmp"] / "nowhere", tiny["tmp"] / "empty"):
        folder.mkdir(exist_ok=True) if folder.name == "empty" else None
        monkeypatch.setenv(zoo.ENV_MODELS, str(folder))
        result = CliRunner().invoke(app, ["models", "list"])
        assert result.exit_code == 2 and f"no shipped models in {folder}" in " ".join(result.output.split())


def test_generated_damage_to_a_zoo_is_refused_before_anything_is_installed(
    trained: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`fftool models install`'s door: Hypothesis damages a packed zoo (bytes flipped, files truncated, removed,
    added or swapped, manifest fields and index entries edited, links planted) and installs it into an empty
    store. Every run installs intact models (each installed file as packed), or ends in one `Error:` line,
    exit 1, with nothing installed; never a traceback."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from tests.test_track_files import FUZZ_EXAMPLES

    base = tmp_path_factory.mktemp("zoo_door")
    monkeypatch.setattr(zoo, "pipelines_root", lambda: trained[0])
    monkeypatch.setenv(zoo.ENV_MODELS, str(base / "pristine"))
    zoo.pack(ArtifactStore(trained[1]), "tiny", ["zara1"])
    pristine = base / "pristine" / "tiny"
    files = sorted(p.relative_to(pristine) for p in pristine.rglob("*") if p.is_file())
    packed = {f: (pristine / f).read_bytes() for f in files}

    def damage(folder: Path, how: str, which: int, where: float, value: object) -> None:
        target = folder / files[which % len(files)]
        data = target.read_bytes()
        at = min(int(where * len(data)), max(len(data) - 1, 0))
        if how == "flip" and data:
            target.write_bytes(data[:at] + bytes([data[at] ^ 0x40]) + data[at + 1 :])
        elif how == "truncate":
            target.write_bytes(data[:at])
        elif how == "remove":
            target.unlink()
        elif how == "add":
            (target.parent / "extra.bin").write_bytes(b"planted")
        elif how == "swap":
            other = folder / files[(which + 1) % len(files)]
            target.write_bytes(other.read_bytes())
        elif how == "link":
            target.unlink()
            target.symlink_to(base / "elsewhere")
        elif how == "json" and target.suffix == ".json":
            record = json.loads(data)
            section = next((v for v in record.values() if isinstance(v, dict) and v), record)
            section[sorted(section)[which % len(section)]] = value
            target.write_text(json.dumps(record))

    @settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
    @given(
        how=st.sampled_from(["flip", "truncate", "remove", "add", "swap", "link", "json"]),
        which=st.integers(0, 10_000),
        where=st.floats(0, 1),
        value=st.one_of(st.none(), st.integers(-5, 5), st.text(max_size=5), st.just("dr"), st.just({})),
    )
    def check(how: str, which: int, where: float, value: object) -> None:
        folder, target = base / "models", base / "target"
        shutil.rmtree(folder, ignore_errors=True)
        shutil.rmtree(target, ignore_errors=True)
        shutil.copytree(pristine, folder / "tiny", symlinks=True)
        damage(folder / "tiny", how, which, where, value)
        monkeypatch.setenv(zoo.ENV_MODELS, str(folder))
        result = CliRunner().invoke(app, ["models", "install", "--profile", "tiny", "--root", str(target)])
        if result.exit_code == 0:
            installed = [p for p in target.rglob("*") if p.is_file() and ".locks" not in p.parts]
            for path in installed:
                if path.name == "manifest.json":
                    continue  # the store may record where and when it installed
                kind_id = path.relative_to(target).parts[:2]
                assert any(
                    f.parts[:2] == kind_id and f.name == path.name and packed[f] == path.read_bytes() for f in files
                ), path
            return
        assert result.exit_code == 1, result.output
        assert result.exception is None or isinstance(result.exception, SystemExit), result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("Error:"), result.output
        assert not any(p.is_file() for kind in zoo.KINDS for p in (target / kind).rglob("*")), "installed in part"

    check()


def test_models_are_listed_installed_and_loaded_without_the_benchmark_data(tiny: dict[str, Path]) -> None:
    """Where the profile's data folders are not there (an installed fftool, a planner's machine), a model is
    checked against the raw files' hashes its lineage recorded: still current, still installable and loadable,
    and still orphaned by a change of the profile that reaches its training inputs."""
    zoo.pack(ArtifactStore(tiny["trained"]), "tiny", ["zara1"])
    profile = tiny["pipelines"] / "tiny.toml"
    text = profile.read_text()
    cfg = load_config(profile)
    away = tiny["tmp"] / "nowhere"
    profile.write_text(text.replace(cfg.data.raw_dir, str(away / "raw")).replace(cfg.data.scenes_dir, str(away)))
    listing = _cli("models", "list", "--profile", "tiny")
    assert "tiny/zara1/dr" in listing and not zoo.orphans(zoo.shipped("tiny"))
    assert "4 model(s) installed" in _cli("models", "install", "--profile", "tiny", "--root", tiny["tmp"] / "fresh")
    assert api.load("tiny/zara1/dr").variant == "dr"
    profile.write_text(profile.read_text() + "\n[windows]\nobs_len = 10\n")
    assert set(zoo.orphans(zoo.shipped("tiny"))) == {m.name for m in zoo.shipped("tiny")}
