"""CVAE training stage on a tiny synthetic benchmark: every variant trains, resumes, and reloads."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from fftool import pipeline
from fftool.artifacts.store import ArtifactStore
from fftool.cli import app
from fftool.config import CVAEConfig, ForcesConfig, load_config
from fftool.errors import IntegrityError
from fftool.learning import cvae_model, training
from fftool.learning.batches import load_scene_set
from fftool.learning.features import prepare
from fftool.learning.training import save_checkpoint
from fftool.models.forceformer import Gaussian
from fftool.stages import cvae
from fftool.stages.contract import StageContext
from fftool.variants import FORCEFORMER_VARIANTS, SPECS, VARIANTS

TINY = CVAEConfig(
    d_model=16,
    n_heads=2,
    d_ff=32,
    n_layers=1,
    z_dim=4,
    k=3,
    train_k=2,
    epochs=2,
    batch_windows=8,
    lr=1e-3,
    val_max_windows=8,
)


@pytest.fixture
def inputs(raw_tree: Path, built_store: ArtifactStore) -> dict:
    cfg = load_config(None, [f"data.raw_dir={str(raw_tree)!r}"])
    return pipeline.run(cfg, built_store, ["forces"])


def _train(inputs: dict, tmp_path: Path, name: str, cfg: CVAEConfig, on_progress=None) -> dict:
    out = tmp_path / name
    out.mkdir(exist_ok=True)
    ctx = StageContext(
        out,
        tmp_path / "scratch",
        benchmark="zara1",
        device_name="cpu",
        **({"on_progress": on_progress} if on_progress else {}),
    )
    return cvae.train(cfg, ForcesConfig(), inputs["windows"], inputs["forces"], ctx)


@pytest.mark.slow
@pytest.mark.parametrize("variant", ["baseline", "goal", "dr", "re"])
def test_every_variant_trains_and_reloads(inputs: dict, tmp_path: Path, variant: str) -> None:
    stats = _train(inputs, tmp_path, variant, TINY.model_copy(update={"variant": variant}))
    assert [row["epoch"] for row in stats["log"]] == [1, 2]
    assert all(row["val_min_ade@3_m"] > 0 for row in stats["log"])
    artifact = type("A", (), {"file": lambda self, name: tmp_path / variant / name})()
    model, cfg, _, _ = cvae_model.load_model(artifact, torch.device("cpu"))
    assert cfg.variant == variant and model.past_embed.inp.in_features == SPECS[variant].feature_dim


def test_features_follow_the_variant(inputs: dict) -> None:
    scenes = load_scene_set(inputs["windows"], inputs["forces"], "zara1", "train")
    batch = scenes.batch(
        scenes.plan(scenes.window_start[:-1].argsort()[:4], 4, 4096, __import__("numpy").random.default_rng(0))[0]
    )
    for variant, spec in SPECS.items():
        prepared = prepare(batch, variant, 8)
        assert prepared.past.shape[-1] == spec.feature_dim
    dr = prepare(batch, "dr", 8)
    torch.testing.assert_close(dr.past[..., 4:6], batch.f_dr[:, :, :8] * batch.agent_mask[..., None, None])
    turned = prepare(batch, "dr", 8, rotate=True, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(  # rotation keeps lengths: forces turn with the scene
        torch.linalg.vector_norm(turned.past[..., 4:6], dim=-1), torch.linalg.vector_norm(dr.past[..., 4:6], dim=-1)
    )
    torch.testing.assert_close(turned.to_world(turned.future_pos), batch.xy[:, :, 8:] * 1.0, atol=1e-4, rtol=0)


@pytest.mark.slow
def test_an_interrupted_run_resumes_to_the_same_weights(inputs: dict, tmp_path: Path) -> None:
    cfg = TINY.model_copy(update={"epochs": 3, "variant": "re"})
    _train(inputs, tmp_path, "reference", cfg)
    (tmp_path / "scratch" / "last.pt").unlink()

    def interrupt(phase: str, done: int, total: int) -> None:
        if phase.startswith("epoch 3/") and done == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _train(inputs, tmp_path, "interrupted", cfg, interrupt)
    resumed = _train(inputs, tmp_path, "resumed", cfg)
    assert resumed["resumed_from_epoch"] == 2
    ref = torch.load(tmp_path / "reference" / "model.pt", weights_only=True)["state_dict"]
    res = torch.load(tmp_path / "resumed" / "model.pt", weights_only=True)["state_dict"]
    for key in ref:
        torch.testing.assert_close(ref[key], res[key])


@pytest.mark.slow
def test_the_cli_trains_a_variant(raw_tree: Path, tmp_path: Path) -> None:
    root = str(tmp_path / "artifacts")
    common = ["--root", root, "--set", f"data.raw_dir={str(raw_tree)!r}"]
    runner = CliRunner()
    assert runner.invoke(app, ["ingest", *common]).exit_code == 0
    assert runner.invoke(app, ["forces", *common]).exit_code == 0
    small = [
        f"cvae.{k}={v}" for k, v in {"d_model": 16, "n_heads": 2, "d_ff": 32, "epochs": 1, "k": 3, "train_k": 2}.items()
    ]
    args = [
        "train-cvae",
        "--benchmarks",
        "zara1",
        "--variant",
        "dr",
        *common,
        *(part for s in small for part in ("--set", s)),
    ]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "val_min_ade@3_m" in result.output
    assert runner.invoke(app, ["train-cvae", "--variant", "rx", *common]).exit_code == 2


def test_a_batched_step_is_the_mean_of_per_window_steps(inputs: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    """Loss and gradients of one padded batch equal the average of the official one-window steps."""
    monkeypatch.setattr(Gaussian, "sample", lambda self, generator=None: self.mu + 0.3)  # no sampling noise
    scenes = load_scene_set(inputs["windows"], inputs["forces"], "zara1", "train")
    _, first = np.unique(scenes.agents(), return_index=True)
    windows = np.r_[first, first[:1] + 1]  # one window per agent count (real padding) and a neighbour
    assert len(first) > 1
    cfg = TINY.model_copy(update={"variant": "re", "dropout": 0.0})
    torch.manual_seed(0)
    model = cvae_model.build_model(cfg)

    def step(members: np.ndarray) -> tuple[float, list[torch.Tensor]]:
        model.zero_grad()
        prepared = prepare(scenes.batch(members), cfg.variant, 8)
        loss = cvae_model.training_loss(model, prepared, cfg, ForcesConfig(), 0.4, torch.Generator()).total
        loss.backward()
        return loss.item(), [p.grad.clone() for p in model.parameters()]

    batched_loss, batched_grads = step(windows)
    singles = [step(windows[i : i + 1]) for i in range(len(windows))]
    assert batched_loss == pytest.approx(np.mean([loss for loss, _ in singles]), rel=1e-5)
    for i, grad in enumerate(batched_grads):
        torch.testing.assert_close(grad, torch.stack([g[i] for _, g in singles]).mean(0), atol=1e-5, rtol=1e-4)


@pytest.mark.slow
def test_loss_decreases_and_a_seeded_run_repeats_exactly(inputs: dict, tmp_path: Path) -> None:
    # "The same numbers" holds for the same machine, torch version and thread count (manifest `environment`).
    cfg = TINY.model_copy(update={"epochs": 4, "variant": "dr"})
    first = _train(inputs, tmp_path, "first", cfg)
    losses = [row["train_loss"] for row in first["log"]]
    assert all(b < a for a, b in itertools.pairwise(losses)) and losses[-1] < 0.9 * losses[0], losses
    (tmp_path / "scratch" / "last.pt").unlink()
    second = _train(inputs, tmp_path, "second", cfg)
    assert [row["train_loss"] for row in second["log"]] == losses  # same seed, same numbers on this machine
    a = torch.load(tmp_path / "first" / "model.pt", weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "second" / "model.pt", weights_only=True)["state_dict"]
    assert all(torch.equal(a[key], b[key]) for key in a)


@pytest.mark.slow
def test_bf16_precision_runs_products_in_bfloat16_and_keeps_losses_float32(inputs: dict, tmp_path: Path) -> None:
    scenes = load_scene_set(inputs["windows"], inputs["forces"], "zara1", "train")
    prepared = prepare(scenes.batch(np.arange(4)), "re", 8)
    losses = {}
    for precision in ("fp32", "bf16"):
        cfg = TINY.model_copy(update={"variant": "re", "precision": precision})
        torch.manual_seed(0)
        model = cvae_model.build_model(cfg)
        seen: set[torch.dtype] = set()
        model.decoder[0].ff[0].register_forward_hook(lambda module, args, out, seen=seen: seen.add(out.dtype))
        parts = cvae_model.training_loss(model, prepared, cfg, ForcesConfig(), 0.4, torch.Generator().manual_seed(0))
        parts.total.backward()
        assert seen == {torch.bfloat16 if precision == "bf16" else torch.float32}
        assert all(part.dtype == torch.float32 and torch.isfinite(part) for part in parts)
        assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)
        losses[precision] = parts.total.item()
    assert losses["bf16"] == pytest.approx(losses["fp32"], rel=0.05)  # the same model, coarser products


@pytest.mark.slow
def test_compiled_layers_compute_the_same_and_keep_parameter_names() -> None:
    cfg = TINY.model_copy(update={"compile": True})
    torch.manual_seed(0)
    compiled = cvae_model.build_model(cfg).eval()
    torch.manual_seed(0)
    plain = cvae_model.build_model(cfg.model_copy(update={"compile": False})).eval()
    assert compiled.state_dict().keys() == plain.state_dict().keys()  # checkpoints load either way
    past, mask = torch.randn(3, 4, 8, SPECS["baseline"].feature_dim), torch.tensor([[1, 1, 1, 0]] * 3, dtype=torch.bool)
    with torch.no_grad():
        torch.testing.assert_close(compiled.encode_past(past, mask)[0], plain.encode_past(past, mask)[0])


def test_learning_rate_schedules_follow_the_step_budget() -> None:
    from fftool.learning.training import lr_factor

    cosine = [lr_factor("cosine", step, 100, 0.1) for step in range(100)]
    assert cosine[0] == pytest.approx(0.1) and cosine[9] == pytest.approx(1.0)  # linear warm-up over 10 steps
    assert cosine[10] == pytest.approx(1.0) and cosine[55] == pytest.approx(0.5)
    assert (np.diff(cosine[9:]) <= 0).all() and cosine[-1] < 1e-3
    assert [lr_factor("constant", step, 100, 0.1) for step in (0, 50)] == [pytest.approx(0.1), 1.0]
    step = [lr_factor("step", 0, 100, 0.0, epoch, 10, 0.5) for epoch in (0, 9, 10, 25, 49)]
    assert step == [1.0, 1.0, 0.5, 0.25, 0.0625]  # StepLR(step_size=10, gamma=0.5), stepped per epoch


@pytest.mark.slow
def test_a_cpu_recipe_builds_trains_and_logs(inputs: dict, tmp_path: Path) -> None:
    """Every recipe option at once on a tiny model: trains, follows its schedule, writes TensorBoard events."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    recipe = {
        "output": "cv_residual", "optimizer": "adamw", "weight_decay": 0.01, "schedule": "cosine",
        "warmup_fraction": 0.2, "grad_clip": 1.0, "out_init_std": 0.001, "epochs": 3, "variant": "dr",
    }  # fmt: skip
    stats = _train(inputs, tmp_path, "recipe", TINY.model_copy(update=recipe))
    log = stats["log"]
    assert [row["lr"] for row in log][-1] < log[0]["lr"] <= TINY.lr  # cosine: falls to ~0 at the end
    assert all(b["agent_windows_seen"] > a["agent_windows_seen"] for a, b in itertools.pairwise(log))
    events = EventAccumulator(str(tmp_path / "recipe" / "tensorboard"))
    events.Reload()
    assert [e.value for e in events.Scalars("val_min_ade@3_m")] == pytest.approx([r["val_min_ade@3_m"] for r in log])
    assert {"train_recon", "train_kl", "train_best_of_k", "lr"} <= set(events.Tags()["scalars"])
    seen = {"train_kl_unclamped", "val_kl_unclamped", "val_posterior_mean_ade", "val_posterior_mean_fde", "val_cv_ade",
            "val_cv_fde", "val_prior_spread_m", "val_z_sensitivity_m"}  # fmt: skip
    assert seen <= set(events.Tags()["scalars"]) and seen <= set(log[0])
    assert all(row["train_kl"] >= TINY.kl_min - 1e-6 for row in log)  # the clamped KL never reads below kl_min,
    assert any(row["train_kl_unclamped"] < TINY.kl_min for row in log)  # the unclamped one does


def test_the_latent_diagnostics_are_computed_as_documented(inputs: dict) -> None:
    """Constant velocity's ADE on validation equals a direct computation; a decoder blind to z has zero
    z-sensitivity and zero prior spread."""
    cfg = TINY.model_copy(update={"output": "cv_residual"})
    val = load_scene_set(inputs["windows"], inputs["forces"], "zara1", "val", reads=())
    subset = cvae_model.val_windows(val, cfg)
    torch.manual_seed(0)
    model = cvae_model.build_model(cfg).eval()
    torch.nn.init.zeros_(model.out.weight)  # the residual head outputs 0: every sample is constant velocity
    found = cvae_model.validate(model, val, subset, cfg, None, None, 8, torch.device("cpu"))
    assert found["z_sensitivity_m"] == pytest.approx(0.0, abs=1e-6) and found["prior_spread_m"] == pytest.approx(
        0.0, abs=1e-5
    )
    assert found["posterior_mean_ade"] == pytest.approx(found["cv_ade"], rel=1e-5)
    xy = val.data.xy[np.isin(np.searchsorted(val.window_start, np.arange(len(val.data)), side="right") - 1, subset)]
    steps = np.arange(1, 13)[None, :, None]
    cv = xy[:, 7:8] + steps * (xy[:, 7:8] - xy[:, 6:7])
    assert found["cv_ade"] == pytest.approx(float(np.linalg.norm(cv - xy[:, 8:], axis=-1).mean()), rel=1e-4)


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["truncated", "another model"])
def test_a_damaged_resume_checkpoint_is_set_aside_and_the_build_starts_over(
    inputs: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, damage: str
) -> None:
    warned: list[str] = []
    monkeypatch.setattr(training, "warn", warned.append)
    _train(inputs, tmp_path, "reference", TINY)
    last = tmp_path / "scratch" / "last.pt"
    if damage == "truncated":
        last.write_bytes(last.read_bytes()[:1000])
    else:
        state = torch.load(last, weights_only=True)
        state["states"]["model"]["out.weight"] = torch.zeros(2, 8)  # the head of a narrower model
        torch.save(state, last)
    rerun = _train(inputs, tmp_path, "rerun", TINY)
    assert rerun["resumed_from_epoch"] == 0 and [row["epoch"] for row in rerun["log"]] == [1, 2]
    (aside,) = (tmp_path / "scratch").glob("last.pt.damaged-*")
    assert len(warned) == 1 and aside.name in warned[0]
    assert torch.load(last, weights_only=True)["epoch"] == 1  # a new checkpoint of the finished run
    ref = torch.load(tmp_path / "reference" / "model.pt", weights_only=True)["state_dict"]
    new = torch.load(tmp_path / "rerun" / "model.pt", weights_only=True)["state_dict"]
    assert all(torch.equal(ref[key], new[key]) for key in ref)  # from the same fresh weights as the first run


@pytest.mark.parametrize("tamper", ["garbage", "pickled function", "goal model"])
def test_a_tampered_model_file_is_one_integrity_error(tmp_path: Path, tamper: str) -> None:
    torch.manual_seed(0)
    path = tmp_path / "model.pt"
    saved = {
        "state_dict": cvae_model.build_model(TINY).state_dict(),
        "config": TINY.model_dump(mode="json"),
        "forces_config": ForcesConfig().model_dump(mode="json"),
        "dt_s": 0.4,
    }
    save_checkpoint(path, saved)
    artifact = type("A", (), {"file": lambda self, name: tmp_path / name})()
    assert cvae_model.load_model(artifact, torch.device("cpu")).config == TINY
    if tamper == "garbage":
        path.write_bytes(b"garbage!" + path.read_bytes()[8:])
    elif tamper == "pickled function":
        torch.save({**saved, "hook": print}, path)
    else:
        torch.save({"state_dict": {}, "in_channels": 14, "config": {"crop_cells": 16}}, path)
    with pytest.raises(IntegrityError) as caught:
        cvae_model.load_model(artifact, torch.device("cpu"))
    message = str(caught.value)
    assert message.startswith(f"{path}: not a valid fftool checkpoint, ")
    assert message.endswith("; rebuild it with `fftool train-cvae --force`")
    assert "weights_only" not in message and "\n" not in message


def test_the_variant_records_cover_the_variants_and_only_forceformer_reads_a_goal() -> None:
    assert tuple(SPECS) == VARIANTS
    assert {variant for variant, spec in SPECS.items() if spec.reads_goal} == set(FORCEFORMER_VARIANTS)
    assert all(set(spec.sampling_reads) <= set(spec.training_reads) for spec in SPECS.values())
