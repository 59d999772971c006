"""`fftool export` of a CVAE that draws its codes from its prior (the shipped dr): the standard normal draws are an
input of its graphs, and given the torch path's draws they give its futures (within 1e-4 m). In a file of its own so
that its export runs beside tests/test_export.py's."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnxruntime
import pytest
import torch
from typer.testing import CliRunner

from fftool import pipeline
from fftool.api import load
from fftool.artifacts.store import Artifact, ArtifactStore
from fftool.cli import app
from fftool.config import predictor_config
from fftool.export import PRIOR_DRAWS
from fftool.learning.observed import desired_speed_and_groups
from fftool.learning.training import generator
from fftool.online import OnlinePredictor

from .conftest import make_raw_tree
from .test_dlow import _cfg


@dataclass(frozen=True)
class Export:
    store: ArtifactStore
    cvae: Artifact
    prior: Path  # the CVAE's export (`fftool export` on its id): drawing from its prior


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> Export:
    """A dr CVAE trained on the tiny data and exported by the command, once."""
    base = tmp_path_factory.mktemp("export_prior")
    store = ArtifactStore(base / "artifacts")
    cvae = pipeline.run(predictor_config(_cfg(make_raw_tree(base / "raw")), "dr"), store, ["cvae"], benchmark="zara1")
    prior = base / "exported_prior"
    result = CliRunner().invoke(app, ["export", cvae["cvae"].id, "--root", str(store.root), "--out", str(prior)])
    assert result.exit_code == 0, result.output
    assert "wrote model.onnx, model_one_goal.onnx " in result.output.replace("\n", " ")
    return Export(store, cvae["cvae"], prior)


@pytest.mark.slow
def test_a_model_drawing_from_its_prior_takes_its_draws_as_an_input(exported: Export) -> None:
    """Without a DLow sampler dr draws its codes from its prior: the graph takes the standard normal draws as
    `noise`; given the draws the torch path makes with a seed, it gives the torch path's futures, and so does the
    online predictor on the export."""
    store, cvae = exported.store, exported.cvae
    model = load(cvae.id, root=store.root)
    assert model.sampler is None and not model.mean_codes("fair")
    manifest = json.loads((exported.prior / "manifest.json").read_text())
    assert list(manifest["inputs"]) == ["past", "agent_mask", "goals", "speed0", "noise"]
    assert list(manifest["one_goal"]["inputs"]) == ["past", "agent_mask", "goal", "speed0", "noise"]
    assert manifest["one_goal"]["codes"] == PRIOR_DRAWS
    z_dim = model.trained.config.z_dim
    assert (manifest["codes"], manifest["z_dim"], manifest["k"]) == (PRIOR_DRAWS, z_dim, 3)
    session = onnxruntime.InferenceSession(str(exported.prior / "model.onnx"), providers=["CPUExecutionProvider"])
    one_goal = onnxruntime.InferenceSession(
        str(exported.prior / "model_one_goal.onnx"), providers=["CPUExecutionProvider"]
    )
    rng = np.random.default_rng(3)
    for agents in (1, 2, 6):
        past = np.cumsum(rng.normal(0.3, 0.1, (1, agents, 8, 2)), 2) + rng.normal(0, 3, (1, agents, 1, 2))
        mask = np.ones((1, agents), bool)
        goals = past[:, :, -1:] + rng.normal(3, 1, (1, agents, 3, 2))
        expected = model.predict(past, mask, k=3, goals=goals, seed=5)
        speed0, _ = desired_speed_and_groups(past, mask, model.trained.forces_config, model.trained.dt_s)
        inputs = {"past": past.astype(np.float32), "agent_mask": mask, "speed0": speed0.astype(np.float32)}
        noise = torch.randn((3, agents, z_dim), generator=generator(5, torch.device("cpu"))).numpy()[None]
        known = inputs | {"goal": goals[:, :, 0].astype(np.float32), "noise": noise}
        inputs |= {"goals": goals.transpose(0, 2, 1, 3).astype(np.float32)}
        got, likely = session.run(None, inputs | {"noise": noise})
        assert got.shape == expected.shape and np.abs(got - expected).max() < 1e-4
        other, same = session.run(None, inputs | {"noise": -noise})  # other draws, other futures, the same centre
        assert np.abs(other - got).max() > 1e-3 and np.array_equal(same, likely)
        assert np.abs(likely - model.most_likely(past, mask, goals=goals[:, :, 0])).max() < 1e-4
        one, _ = one_goal.run(None, known)  # one goal per agent: the torch path's draws for a known goal
        assert np.abs(one - model.predict(past, mask, k=3, goals=goals[:, :, 0], seed=5)).max() < 1e-4

    by_graph, by_torch = OnlinePredictor(exported.prior, k=3, seed=5), OnlinePredictor(model, k=3, seed=5)
    for step in range(9):
        detections = {agent: (0.5 * step * (agent - 6), 0.3 * agent - 0.1 * step) for agent in (7, 8, 9)}
        goals = {agent: (8.0 + agent, -2.0) for agent in detections}
        graph = by_graph.update(0.4 * step, detections, goals)
        torch_path = by_torch.update(0.4 * step, detections, goals)
        assert list(graph.agents) == list(torch_path.agents) == ([7, 8, 9] if step >= 7 else [])
        assert np.abs(graph.futures - torch_path.futures).max(initial=0.0) < 1e-4
        assert np.abs(graph.most_likely - torch_path.most_likely).max(initial=0.0) < 1e-4
