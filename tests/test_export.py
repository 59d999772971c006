"""`fftool export`: the ONNX graphs of a CVAE (each goal from its prior's mean code, a DLow sampler's codes for a
known goal) give the torch path's futures and most-likely future (within 1e-4 m) for any number of agents, run by
onnxruntime alone; its folder is fftool's own. A CVAE drawing from its prior: tests/test_export_prior.py."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnxruntime
import pytest
import torch
from typer.testing import CliRunner

from fftool import pipeline
from fftool.api import Model, load, load_goal_sampler
from fftool.artifacts.store import Artifact, ArtifactStore
from fftool.cli import app
from fftool.config import predictor_config
from fftool.errors import UsageError
from fftool.export import DLOW_CODES, EXPORT, MEAN_CODES, PRIOR_DRAWS, export
from fftool.learning.observed import desired_speed_and_groups
from fftool.online import OnlinePredictor
from fftool.outputs import check_output

from .conftest import make_raw_tree
from .test_dlow import _cfg


@dataclass(frozen=True)
class Export:
    store: ArtifactStore
    cvae: Artifact
    dlow: Artifact
    goal: Artifact
    out: Path
    model: Model  # what `out` exports: the CVAE decoding each of K goals from its prior's mean, DLow codes for one


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> Export:
    """A dr model, its DLow sampler and a goal U-Net trained on the tiny data and exported together, as the shipped
    re is (each of K goals from the prior's mean code, the sampler's codes toward a known goal), once: an export
    unrolls the decoder's 12 steps, the slow part of these tests (tests/test_export_prior.py exports the CVAE
    drawing from its prior, in a file of its own so that the two exports run side by side)."""
    base = tmp_path_factory.mktemp("export")
    store = ArtifactStore(base / "artifacts")
    cfg = predictor_config(_cfg(make_raw_tree(base / "raw"), "goal.neighbour_channels=true"), "dr")
    built = pipeline.run(cfg, store, ["dlow", "goal"], benchmark="zara1")
    cvae, dlow, goal = built["cvae"], built["dlow"], built["goal"]
    model = dataclasses.replace(load(cvae.id, root=store.root, dlow=dlow.id), fair_code="mean")
    out = base / "exported"
    source = {"model": cvae.id, **model.fingerprints, "goal_model": goal.id}
    export(model, out, source, load_goal_sampler(goal.id, root=store.root))
    return Export(store, cvae, dlow, goal, out, model)


@pytest.mark.slow
def test_an_exported_dr_gives_the_torch_futures_for_any_number_of_agents(exported: Export) -> None:
    store, cvae, dlow, out, model = exported.store, exported.cvae, exported.dlow, exported.out, exported.model
    manifest = json.loads((out / "manifest.json").read_text())
    assert list(manifest["inputs"]) == ["past", "agent_mask", "goals", "speed0"] and manifest["k"] == 3
    assert list(manifest["one_goal"]["inputs"]) == ["past", "agent_mask", "goal", "speed0"]
    assert (manifest["codes"], manifest["one_goal"]["codes"]) == (MEAN_CODES, DLOW_CODES)
    source = {"model": cvae.id, "cvae": cvae.fingerprint, "dlow": dlow.fingerprint, "goal_model": exported.goal.id}
    assert manifest["source"] == source
    session = onnxruntime.InferenceSession(str(out / "model.onnx"), providers=["CPUExecutionProvider"])
    one_goal = onnxruntime.InferenceSession(str(out / "model_one_goal.onnx"), providers=["CPUExecutionProvider"])
    assert load(dlow.id, root=store.root).fingerprints == model.fingerprints  # a sampler brings its CVAE
    rng = np.random.default_rng(1)
    for agents in (1, 2, 6):
        past = np.cumsum(rng.normal(0.3, 0.1, (1, agents, 8, 2)), 2) + rng.normal(0, 3, (1, agents, 1, 2))
        mask = np.ones((1, agents), bool)
        mask[0, -1] = agents < 3  # a padded slot, whatever it holds
        goals = past[:, :, -1:] + rng.normal(3, 1, (1, agents, 3, 2))  # (B, A, K, 2): sample k heads to goal k
        expected = model.predict(past, mask, k=3, goals=goals)  # (B, K, A, 12, 2)
        speed0, _ = desired_speed_and_groups(past, mask, model.trained.forces_config, model.trained.dt_s)
        inputs = {"past": past.astype(np.float32), "agent_mask": mask, "speed0": speed0.astype(np.float32)}
        got, likely = session.run(None, inputs | {"goals": goals.transpose(0, 2, 1, 3).astype(np.float32)})
        assert got.shape == expected.shape
        assert np.abs(got - expected)[:, :, mask[0]].max() < 1e-4
        centre = model.most_likely(past, mask, goals=goals[:, :, 0])  # the prior's mean code toward goal 1
        assert likely.shape == centre.shape and np.abs(likely - centre)[:, mask[0]].max() < 1e-4
        known = model.predict(past, mask, k=3, goals=goals[:, :, 0])  # one goal per agent: the sampler's codes
        got, likely = one_goal.run(None, inputs | {"goal": goals[:, :, 0].astype(np.float32)})
        assert np.abs(got - known)[:, :, mask[0]].max() < 1e-4 and np.abs(likely - centre)[:, mask[0]].max() < 1e-4
        repeated = np.repeat(goals[:, None, :, 0], 3, 1).astype(np.float32)  # goal 1 as each sample's goal
        other, _ = session.run(None, inputs | {"goals": repeated})
        assert np.abs(other - got)[:, :, mask[0]].max() > 1e-2  # decodes the prior's mean, not the sampler's codes

    # The online predictor on the export (onnxruntime) gives the torch one's futures, update by update: here every
    # goal is passed, so both decode the sampler's codes toward it (model_one_goal.onnx).
    with pytest.raises(UsageError, match="exported with K = 3"):
        OnlinePredictor(out)
    by_graph, by_torch = OnlinePredictor(out, k=3), OnlinePredictor(model, k=3)
    for step in range(10):
        detections = {agent: (0.5 * step * (agent - 6), 0.3 * agent - 0.1 * step) for agent in (7, 8, 9)}
        goals = {agent: (8.0 + agent, -2.0) for agent in detections}
        graph, torch_path = (
            by_graph.update(0.4 * step, detections, goals),
            by_torch.update(0.4 * step, detections, goals),
        )
        assert list(graph.agents) == list(torch_path.agents) == ([7, 8, 9] if step >= 7 else [])
        np.testing.assert_allclose(graph.goals, torch_path.goals)
        assert graph.futures.shape == torch_path.futures.shape
        assert graph.most_likely.shape == torch_path.most_likely.shape
        assert np.abs(graph.futures - torch_path.futures).max(initial=0.0) < 1e-4
        assert np.abs(graph.most_likely - torch_path.most_likely).max(initial=0.0) < 1e-4


@pytest.mark.slow
def test_an_exported_goal_unet_draws_the_torch_goals(exported: Export) -> None:
    """A goal variant exported with its goal U-Net: goal_unet.onnx gives the torch goal maps (within 1e-4 of a
    logit), and the online predictor on the export draws its own goals and gives the torch path's futures."""
    store, goal, out = exported.store, exported.goal, exported.out
    assert sorted(p.name for p in out.iterdir()) == [
        "goal_unet.onnx",
        "manifest.json",
        "model.onnx",
        "model_one_goal.onnx",
    ]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["goal_unet"]["crop_cells"] == goal.manifest.params["crop_cells"]
    sampler = load_goal_sampler(goal.id, root=store.root)
    session = onnxruntime.InferenceSession(str(out / "goal_unet.onnx"), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(2)
    for agents in (1, 2, 7):
        past = (np.cumsum(rng.normal(0.3, 0.1, (agents, 8, 2)), 1) + rng.normal(0, 3, (agents, 1, 2))).astype(
            np.float32
        )
        got = session.run(None, {"past": past})
        expected = sampler.maps(torch.as_tensor(past), 12)
        for graph_part, torch_part in zip(got, expected):
            assert graph_part.shape == tuple(torch_part.shape)
            assert np.abs(graph_part - torch_part.detach().numpy()).max() < 1e-4

    by_graph, by_torch = OnlinePredictor(out, k=3), OnlinePredictor(exported.model, k=3, goal_sampler=sampler)
    for step in range(9):
        detections = {agent: (0.5 * step * (agent - 6), 0.3 * agent - 0.1 * step) for agent in (7, 8, 9)}
        graph, torch_path = by_graph.update(0.4 * step, detections), by_torch.update(0.4 * step, detections)
        assert list(graph.agents) == list(torch_path.agents) == ([7, 8, 9] if step >= 7 else [])
        assert np.abs(graph.goals - torch_path.goals).max(initial=0.0) < 1e-4  # drawn, not passed
        assert np.abs(graph.futures - torch_path.futures).max(initial=0.0) < 1e-4


def test_an_export_never_replaces_a_users_folder(tmp_path: Path) -> None:
    earlier = tmp_path / "earlier"  # an export fftool wrote may be replaced
    earlier.mkdir()
    (earlier / "model.onnx").write_bytes(b"")
    (earlier / "manifest.json").write_text(json.dumps({"format": "ONNX, opset 18"}))
    check_output(earlier, "--out", EXPORT)
    (earlier / "manifest.json").write_text("{}")
    with pytest.raises(UsageError, match="not an export's"):
        check_output(earlier, "--out", EXPORT)
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    result = CliRunner().invoke(app, ["export", "cvae/0123456789ab", "--out", str(mine)])
    assert result.exit_code == 2 and "did not write (notes.txt)" in result.output
    assert (mine / "notes.txt").read_text() == "mine"


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ({"variant": "dx"}, "variant 'dx' is none of"),
        ({"inputs": {"past": {}, "agent_mask": {}}}, r"inputs \['past', 'agent_mask'\], expected .*'speed0'"),
        ({"forces": {"fov_deg": "wide"}}, "forces.fov_deg: "),
        ({"k": None} | {"drop": "k"}, r"missing \['k'\]"),
        ({"goal_unet": {"config": {"crop_cells": "wide"}}}, "goal_unet: expected its config and sampling"),
        ({"codes": PRIOR_DRAWS}, "z_dim: expected the codes' size"),
        ({"outputs": {"futures": "(1, 3, A, 12, 2)"}}, "outputs: expected futures and most_likely .*export again"),
        ({"drop": "one_goal"}, "one_goal: expected the known-goal graph .*export again"),
        ({"one_goal": {"inputs": {"past": {}}}}, r"one_goal.inputs \['past'\], expected"),
    ],
)
def test_a_damaged_export_manifest_is_one_input_error(tmp_path: Path, edit: dict, message: str) -> None:
    """Before: an unknown variant raised a bare KeyError and a bad forces block pydantic's own error."""
    from fftool.errors import InputError
    from fftool.exported import ExportedModel

    manifest = {"format": "ONNX, opset 18", "variant": "dr", "k": 3, "obs_len": 8, "pred_len": 12, "step_s": 0.4}
    outputs = {"futures": "(1, 3, A, 12, 2)", "most_likely": "(1, A, 12, 2)"}
    manifest["inputs"], manifest["outputs"] = {name: {} for name in ("past", "agent_mask", "goals", "speed0")}, outputs
    manifest["one_goal"] = {
        "inputs": {name: {} for name in ("past", "agent_mask", "goal", "speed0")},
        "outputs": outputs,
    }
    manifest |= {key: value for key, value in edit.items() if key != "drop"}
    manifest.pop(edit.get("drop", ""), None)
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(InputError, match=message):
        ExportedModel.load(tmp_path)
