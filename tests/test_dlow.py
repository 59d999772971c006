"""AgentFormer's DLow sampler on a tiny synthetic benchmark: its loss by hand, training, resuming,
deterministic test-time codes, evaluate drawing through it; and the batch planner's agent cap."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from fftool import pipeline
from fftool.artifacts.schema import DLOW_MODEL_FILE
from fftool.artifacts.store import ArtifactStore
from fftool.config import load_config
from fftool.learning.batches import load_scene_set
from fftool.learning.cvae_model import epoch_plan
from fftool.learning.training import lr_factor
from fftool.models.dlow import Codes, QNet, dlow_loss
from fftool.models.forceformer import Gaussian
from fftool.stages import dlow as dlow_stage

TINY = [
    "cvae.d_model=16", "cvae.n_heads=2", "cvae.d_ff=32", "cvae.n_layers=1", "cvae.z_dim=4", "cvae.k=3",
    "cvae.train_k=2", "cvae.epochs=1", "cvae.val_max_windows=4", "evaluate.k=3",
    "dlow.k=3", "dlow.qnet_hidden=[8]", "dlow.epochs=2", "dlow.lr=1e-2", "dlow.val_max_windows=4",
    "dlow.variants=['baseline', 'dr']",
]  # fmt: skip


def _cfg(raw: Path, *more: str):
    return load_config(None, [f"data.raw_dir={str(raw)!r}", *TINY, *more])


def test_the_loss_is_agentformers_on_a_hand_computed_case() -> None:
    """One window, one agent, K = 2 codes of dimension 1, futures of one step: every term by hand."""
    samples = torch.tensor([[[[[1.0, 0.0]]], [[[0.0, 2.0]]]]])  # (B=1, K=2, A=1, T=1, 2)
    future = torch.zeros(1, 1, 1, 2)
    codes = Codes(A=torch.tensor([[[[1.0], [2.0]]]]), b=torch.tensor([[[[0.0], [1.0]]]]))  # (1, 1, 2, 1)
    prior = Gaussian(torch.zeros(1, 1, 1), torch.zeros(1, 1, 1))
    parts = dlow_loss(samples, future, codes, prior, torch.ones(1, 1, dtype=torch.bool),
                      recon_weight=5, diverse_weight=2, d_scale=4, kl_weight=0.1, kl_min=0.5)  # fmt: skip
    recon = min(1.0, 4.0)  # best of K squared error
    diverse = math.exp(-(1 + 4) / 4)  # one pair, d² = 1² + 2²
    kl = sum(0.5 * (a * a + b * b - 1 - math.log(a * a + 1e-8)) for a, b in ((1.0, 0.0), (2.0, 1.0)))
    assert parts.recon.item() == pytest.approx(recon)
    assert parts.diverse.item() == pytest.approx(diverse)
    assert parts.kl_unclamped.item() == pytest.approx(kl, rel=1e-5)
    assert parts.total.item() == pytest.approx(5 * recon + 2 * diverse + 0.1 * max(kl, 0.5), rel=1e-5)


def test_codes_are_b_at_test_and_share_one_eps() -> None:
    torch.manual_seed(0)
    net = QNet(d_model=6, z_dim=3, k=4, hidden=(5,))
    codes = net(torch.randn(2, 3, 6))
    assert codes.b.shape == codes.A.shape == (2, 3, 4, 3)
    assert torch.equal(codes.z(mean=True), codes.b)
    drawn = codes.z(mean=False, generator=torch.Generator().manual_seed(0))
    # One ε per latent dimension for every window, agent and code: read it where |A| is largest (dividing by
    # an A near 0 amplifies rounding), then every draw must be b + A·ε.
    where = codes.A.abs().flatten(0, 2).argmax(0)  # (Z,)
    eps = ((drawn - codes.b) / codes.A).flatten(0, 2)[where, torch.arange(3)]
    assert torch.allclose(drawn, codes.b + codes.A * eps, atol=1e-6)


def test_the_linear_schedule_is_agentformers() -> None:
    factors = [lr_factor("linear", 0, 1, 0.0, epoch, epochs=50, fix_epochs=10) for epoch in range(50)]
    assert factors[:11] == [1.0] * 11 and factors[11] == pytest.approx(1 - 1 / 41)
    assert factors[-1] == pytest.approx(1 - 39 / 41)


def test_a_crowded_window_is_planned_by_the_agents_it_carries(raw_tree: Path, built_store: ArtifactStore) -> None:
    """With max_agents = 2, a 3-agent window costs a 2-agent window's share of the pair budget: batches
    planned by capped counts hold as many windows as the budget allows."""
    cfg = load_config(None, [f"data.raw_dir={str(raw_tree)!r}"])
    windows = pipeline.run(cfg, built_store, ["windows"])["windows"]
    scenes = load_scene_set(windows, None, "zara1", "train", reads=())
    crowded = np.flatnonzero(scenes.agents() == 3)
    assert len(crowded) >= 8
    rng = np.random.default_rng(0)
    budget = 4 * 2**2  # four windows of two agents
    uncapped = scenes.plan(crowded, 32, budget, rng)
    capped = scenes.plan(crowded, 32, budget, rng, max_agents=2)
    assert max(map(len, uncapped)) == 1  # 2 × 3² > 16: before the fix every crowded window took a step alone
    assert max(map(len, capped)) == 4
    cvae_cfg = cfg.cvae.model_copy(update={"max_agents": 2, "max_agent_pairs": budget})
    plan, _ = epoch_plan(scenes, cvae_cfg, 0, scenes.windows)
    with_crowded = [batch for batch in plan if (scenes.agents()[batch] == 3).any()]
    assert all(len(batch) <= 4 for batch in with_crowded) and any(len(batch) > 1 for batch in with_crowded)


@pytest.mark.slow
def test_dlow_trains_resumes_and_evaluate_draws_through_it(
    raw_tree: Path, built_store: ArtifactStore, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg, cpu, store = _cfg(raw_tree), pipeline.Runtime("cpu"), built_store
    built = pipeline.run(cfg, store, ["dlow"], benchmark="zara1", runtime=cpu)
    stats = built["dlow"].manifest.stats
    assert [row["epoch"] for row in stats["log"]] == [1, 2] and stats["variant"] == "baseline"
    assert {"train_recon", "train_diverse", "train_kl", "train_kl_unclamped", "val_min_ade@3_m"} <= set(stats["log"][0])
    assert stats["preset"]["diverse_weight"] == 5.0 and stats["preset"]["schedule"] == "linear"  # zara1's
    weights = torch.load(built["dlow"].file(DLOW_MODEL_FILE), weights_only=True)["state_dict"]

    # killed during epoch 2, then run again: it resumes from epoch 1's checkpoint to the same weights
    again = ArtifactStore(tmp_path / "again")
    pipeline.run(cfg, again, ["cvae"], benchmark="zara1", runtime=cpu)
    real_steps = dlow_stage._Trainer.steps

    def killed_in_epoch_2(self, epoch):
        if epoch == 1:
            raise KeyboardInterrupt
        return real_steps(self, epoch)

    monkeypatch.setattr(dlow_stage._Trainer, "steps", killed_in_epoch_2)
    with pytest.raises(KeyboardInterrupt):
        pipeline.run(cfg, again, ["dlow"], benchmark="zara1", runtime=cpu)
    monkeypatch.setattr(dlow_stage._Trainer, "steps", real_steps)
    resumed = pipeline.run(cfg, again, ["dlow"], benchmark="zara1", runtime=cpu)["dlow"]
    assert resumed.manifest.stats["resumed_from_epoch"] == 1
    resumed_weights = torch.load(resumed.file(DLOW_MODEL_FILE), weights_only=True)["state_dict"]
    assert all(torch.equal(weights[name], resumed_weights[name]) for name in weights)

    # evaluate draws through the sampler, with no random draw at test (z = b): another seed, the same numbers
    evaluation = pipeline.run(cfg, store, ["evaluate"], benchmark="zara1", runtime=cpu)["evaluate"]
    assert evaluation.manifest.stats["sampler"] == "dlow" and "dlow" in evaluation.manifest.sources
    seeded = cfg.model_copy(update={"evaluate": cfg.evaluate.model_copy(update={"seed": 5})})
    other_seed = pipeline.run(seeded, store, ["evaluate"], benchmark="zara1", runtime=cpu)["evaluate"]
    assert other_seed.manifest.stats["min_ade"] == evaluation.manifest.stats["min_ade"]
    without = cfg.model_copy(update={"dlow": cfg.dlow.model_copy(update={"variants": ()})})
    prior = pipeline.run(without, store, ["evaluate"], benchmark="zara1", runtime=cpu)["evaluate"].manifest.stats
    assert prior["sampler"] == "cvae prior" and prior["min_ade"] != evaluation.manifest.stats["min_ade"]


def test_the_fair_protocol_decodes_code_j_for_goal_j(raw_tree: Path, built_store: ArtifactStore) -> None:
    """Under the fair protocol each sample has its own goal, so its own past: sample j decodes code j of the
    sampler applied to that sample's context (the same code as the paper protocol when the goals agree)."""
    from fftool.learning.cvae_model import build_model, sample
    from fftool.learning.features import prepare
    from fftool.learning.protocols import repeat_windows

    cfg = _cfg(raw_tree)
    windows = pipeline.run(cfg, built_store, ["windows"])["windows"]
    scenes = load_scene_set(windows, None, "zara1", "test", reads=())
    torch.manual_seed(0)
    model, sampler = build_model(cfg.cvae).eval(), QNet(16, 4, 3, (8,)).eval()
    batch = scenes.batch(np.arange(2))
    prepared = prepare(batch, "baseline", 8)
    all_codes = sample(model, prepared, cfg.cvae, None, None, 3, sampler=sampler)  # (B, K, A, T, 2)
    repeated = prepare(repeat_windows(batch, 3), "baseline", 8)
    pick = torch.arange(3).repeat(2)
    one_each = sample(model, repeated, cfg.cvae, None, None, 1, sampler=sampler, pick=pick)  # (B·K, 1, A, T, 2)
    assert torch.allclose(one_each.view(2, 3, *one_each.shape[2:]), all_codes, atol=1e-5)
