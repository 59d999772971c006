"""Goal protocols and test-time inputs: the paper protocol's closest goal, the fair protocol's blindness to
the ground truth, past forces recomputed exactly as the forces stage computes them, the CV reference."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from fftool import pipeline
from fftool.artifacts.schema import CVAE_MODEL_FILE
from fftool.artifacts.store import ArtifactStore
from fftool.config import CVAEConfig, EvaluateConfig, ForcesConfig, load_config
from fftool.learning import cvae_model
from fftool.learning.batches import SceneBatch, load_scene_set
from fftool.learning.protocols import constant_velocity, protocol_goals, with_forces, with_past_forces
from fftool.learning.sampling import Predictor
from fftool.learning.training import save_checkpoint


def test_paper_protocol_gives_every_sample_the_goal_closest_to_the_truth() -> None:
    sampled = torch.tensor([[[[5.0, 5.0], [1.0, 0.5], [0.0, 3.0]]]])  # (B=1, A=1, K=3, 2)
    truth_end = torch.tensor([[[1.0, 1.0]]])
    goals = protocol_goals("paper", sampled, truth_end, 3)
    assert goals.shape == (1, 3, 1, 2)
    assert goals[0, :, 0].tolist() == [[1.0, 0.5]] * 3
    fair = protocol_goals("fair", sampled, truth_end, 3)
    assert fair[0, :, 0].tolist() == sampled[0, 0].tolist()  # sample k uses goal k
    assert protocol_goals("oracle", sampled, truth_end, 3)[0, :, 0].tolist() == [[1.0, 1.0]] * 3


@pytest.fixture
def scene(raw_tree: Path, built_store: ArtifactStore) -> dict:
    cfg = load_config(None, [f"data.raw_dir={str(raw_tree)!r}"])
    built = pipeline.run(cfg, built_store, ["forces"])
    scenes = load_scene_set(built["windows"], built["forces"], "zara1", "test")
    return {"scenes": scenes, "batch": scenes.batch(np.arange(min(scenes.windows, 6)))}


def test_past_forces_recomputed_toward_the_true_goal_equal_the_stored_ones(scene: dict) -> None:
    batch: SceneBatch = scene["batch"]
    again = with_past_forces(batch, batch.xy[:, :, -1], ForcesConfig(), 0.4, 8, ("f_dr", "f_re"))
    mask = batch.agent_mask
    torch.testing.assert_close(again.f_dr[:, :, :8][mask], batch.f_dr[:, :, :8][mask], atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(again.f_re[:, :, :8][mask], batch.f_re[:, :, :8][mask], atol=1e-4, rtol=1e-4)
    assert again.f_dr[:, :, 8:].abs().sum() == 0  # the future forces are never handed to the sampler
    dr_only = with_past_forces(batch, batch.xy[:, :, -1], ForcesConfig(), 0.4, 8, ("f_dr", "speed0"))
    assert torch.equal(dr_only.f_dr, again.f_dr) and dr_only.f_re.abs().sum() == 0  # what dr reads, nothing else


def test_all_forces_recomputed_toward_the_true_goal_equal_the_stored_ones(scene: dict) -> None:
    """Training with goals other than the true end point recomputes every step's forces toward them: with the
    true end point, that gives back what the forces stage stored, future steps included."""
    batch: SceneBatch = scene["batch"]
    again = with_forces(batch, batch.xy[:, :, -1], ForcesConfig(), 0.4, 8, ("f_dr", "f_re"))
    mask = batch.agent_mask
    torch.testing.assert_close(again.f_dr[mask], batch.f_dr[mask], atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(again.f_re[mask], batch.f_re[mask], atol=1e-4, rtol=1e-4)


def _predictor(tmp_path: Path, protocol: str, sampled: np.ndarray) -> Predictor:
    cfg = CVAEConfig(variant="re", d_model=16, n_heads=2, d_ff=32, n_layers=1, z_dim=4, dropout=0.0)
    torch.manual_seed(0)
    model = cvae_model.build_model(cfg)
    save_checkpoint(
        tmp_path / CVAE_MODEL_FILE,
        {
            "state_dict": model.state_dict(),
            "config": cfg.model_dump(mode="json"),
            "forces_config": ForcesConfig().model_dump(mode="json"),
            "dt_s": 0.4,
        },
    )
    artifact = type("Artifact", (), {"file": lambda self, name: tmp_path / name})()
    trained = cvae_model.load_model(artifact, torch.device("cpu"))
    return Predictor(EvaluateConfig(protocol=protocol, k=4), trained, sampled, 8, 12, torch.device("cpu"))


def _perturb_future(batch: SceneBatch) -> SceneBatch:
    xy = batch.xy.clone()
    xy[:, :, 8:] += torch.randn(xy[:, :, 8:].shape, generator=torch.Generator().manual_seed(9)) * 3.0
    return SceneBatch(xy, batch.agent_mask, batch.f_dr * 7, batch.f_re * 7, batch.speed0, batch.group, batch.row)


@pytest.mark.parametrize(("protocol", "reads_truth"), [("fair", False), ("paper", True), ("oracle", True)])
def test_only_the_fair_protocol_ignores_the_ground_truth_future(
    scene: dict, tmp_path: Path, protocol: str, reads_truth: bool
) -> None:
    scenes, batch = scene["scenes"], scene["batch"]
    rng = np.random.default_rng(0)
    sampled = scenes.data.xy[:, -1, None, :] + rng.normal(0, 2.0, (len(scenes.data), 4, 2))  # (M, K, 2)
    positions = np.where(batch.row.numpy() >= 0, np.searchsorted(scenes.data.row, batch.row.numpy()), -1)

    def predict(b: SceneBatch) -> torch.Tensor:
        predictor = _predictor(tmp_path, protocol, sampled)  # same seed: same noise
        with torch.no_grad():
            return predictor(b, predictor.goals(b, positions))

    mask = batch.agent_mask[:, None].expand(-1, 4, -1)
    same = torch.allclose(predict(batch)[mask], predict(_perturb_future(batch))[mask])
    assert same != reads_truth


def test_constant_velocity_extrapolates_the_last_step() -> None:
    past = torch.tensor([[[[0.0, 0.0], [1.0, 0.5]]]])  # (B=1, A=1, Tp=2, 2)
    futures = constant_velocity(past, 3, 5, 15.0, 0.2, torch.Generator().manual_seed(0))
    assert futures.shape == (1, 5, 1, 3, 2)
    assert futures[0, 0, 0].tolist() == [[2.0, 1.0], [3.0, 1.5], [4.0, 2.0]]  # sample 0: no noise
    assert not torch.allclose(futures[0, 1], futures[0, 0])
