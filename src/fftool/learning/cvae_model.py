"""The CVAE as functions: build it, its training loss and epoch plan, validation, drawing K futures, and
loading a trained one from its artifact alone.

Shared by the `cvae` stage (training, validation), `evaluate` and `plot`, which never import each other.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import torch

from fftool.artifacts.schema import CVAE_MODEL_FILE
from fftool.artifacts.store import Artifact
from fftool.config import CVAEConfig, ForcesConfig
from fftool.learning.batches import SceneSet
from fftool.learning.features import DECODER_DIMS, FEATURE_DIMS, Prepared, decoder_features, prepare
from fftool.learning.training import epoch_seed, generator, model_file, validation_subset
from fftool.models.forceformer import ForceFormer, LossParts
from fftool.science.metrics import ade_fde


def build_model(cfg: CVAEConfig) -> ForceFormer:
    model = ForceFormer(
        input_dim=FEATURE_DIMS[cfg.variant],
        decoder_dim=DECODER_DIMS[cfg.variant],
        d_model=cfg.d_model,
        n_heads=cfg.n_heads,
        d_ff=cfg.d_ff,
        dropout=cfg.dropout,
        n_layers=cfg.n_layers,
        z_dim=cfg.z_dim,
        output=cfg.output,
        out_init_std=cfg.out_init_std,
    )
    if cfg.compile:  # in place: parameter names (and saved checkpoints) stay the same
        for layer in (*model.encoder, *model.future_encoder, *model.decoder):
            layer.compile(dynamic=True)
    return model


def autocast(cfg: CVAEConfig, device: torch.device) -> torch.autocast:
    """bfloat16 matrix products when the config asks for it; losses and latent Gaussians stay float32."""
    return torch.autocast(device.type, dtype=torch.bfloat16, enabled=cfg.precision == "bf16")


def sample(
    model: ForceFormer,
    prepared: Prepared,
    cfg: CVAEConfig,
    forces_cfg: ForcesConfig | None,
    dt_s: float | None,
    k: int,
    generator_: torch.Generator | None = None,
) -> torch.Tensor:
    """K futures per agent from the prior: (B, K, A, Tf, 2) in the normalised frame."""
    with autocast(cfg, prepared.past.device):
        tokens, agent_context = model.encode_past(prepared.past, prepared.agent_mask)
        return model.sample(
            model.prior(agent_context),
            tokens,
            prepared.agent_mask,
            prepared.past_pos[:, :, -1],
            prepared.last_step,
            prepared.future_pos.shape[2],
            decoder_features(cfg.variant, prepared, forces_cfg, dt_s, repeat=k),
            k,
            generator_,
        )


def epoch_plan(
    train: SceneSet, cfg: CVAEConfig, epoch: int, n_windows: int
) -> tuple[list[np.ndarray], np.random.Generator]:
    """The batches of one epoch (seeded by (seed, epoch)) and the generator that goes on to draw agent caps."""
    rng = np.random.default_rng(epoch_seed(cfg.seed, epoch))
    return train.plan(rng.permutation(train.windows)[:n_windows], cfg.batch_windows, cfg.max_agent_pairs, rng), rng


def training_loss(
    net: torch.nn.Module,
    prepared: Prepared,
    cfg: CVAEConfig,
    forces_cfg: ForcesConfig | None,
    dt_s: float | None,
    gen: torch.Generator,
) -> LossParts:
    """AgentFormer's loss parts for one batch (posterior reconstruction, KL, best-of-train_k): the model's
    forward, called through `net` (the model, or the model in DistributedDataParallel)."""
    with autocast(cfg, prepared.past.device):
        return net(
            prepared.past,
            prepared.future,
            prepared.future_pos,
            prepared.agent_mask,
            prepared.past_pos[:, :, -1],
            prepared.last_step,
            decoder_features(cfg.variant, prepared, forces_cfg, dt_s),
            decoder_features(cfg.variant, prepared, forces_cfg, dt_s, repeat=cfg.train_k),
            cfg.train_k,
            cfg.kl_min,
            gen,
        )


@torch.no_grad()
def val_metrics(
    scenes: SceneSet,
    windows: np.ndarray,
    cfg: CVAEConfig,
    obs_len: int,
    device: torch.device,
    predict: Callable[[Prepared], torch.Tensor],
) -> tuple[float, float]:
    """minADE_K and minFDE_K (metres, minima per agent, independent) of `predict`'s (B, K, A, Tf, 2)
    futures in the normalised frame (rotation-free here: metres as is), ground-truth goals."""
    ade, fde, count = 0.0, 0.0, 0
    for members in scenes.plan(windows, cfg.batch_windows, cfg.max_agent_pairs, np.random.default_rng(0)):
        prepared = prepare(scenes.batch(members).to(device), cfg.variant, obs_len)
        sample_ade, sample_fde = ade_fde(predict(prepared), prepared.future_pos)  # (B, K, A)
        mask = prepared.agent_mask
        ade += float((sample_ade.min(1).values * mask).sum())
        fde += float((sample_fde.min(1).values * mask).sum())
        count += int(mask.sum())
    return ade / max(count, 1), fde / max(count, 1)


def validate(
    model: ForceFormer,
    scenes: SceneSet,
    windows: np.ndarray,
    cfg: CVAEConfig,
    forces_cfg: ForcesConfig | None,
    dt_s: float | None,
    obs_len: int,
    device: torch.device,
) -> tuple[float, float]:
    """The model's validation minADE_K / minFDE_K with K = cfg.k prior samples."""
    model.eval()
    gen = generator(cfg.seed, device)
    return val_metrics(
        scenes,
        windows,
        cfg,
        obs_len,
        device,
        lambda prepared: sample(model, prepared, cfg, forces_cfg, dt_s, cfg.k, gen),
    )


def val_windows(scenes: SceneSet, cfg: CVAEConfig) -> np.ndarray:
    """The fixed validation subset: `val_max_windows` windows drawn with the run's seed (all if 0)."""
    return validation_subset(scenes.windows, cfg.val_max_windows, cfg.seed)


class Trained(NamedTuple):
    model: ForceFormer  # in eval mode
    config: CVAEConfig
    forces_config: ForcesConfig | None  # the force constants it decodes with (None: a variant without forces)
    dt_s: float | None  # the time step its forces were computed with


def load_model(cvae: Artifact, device: torch.device) -> Trained:
    """Rebuild a trained model from its artifact alone (a damaged model file is an IntegrityError)."""
    with model_file(cvae.file(CVAE_MODEL_FILE), device, "fftool train-cvae --force") as saved:
        cfg = CVAEConfig.model_validate(saved["config"])
        model = build_model(cfg).to(device)
        model.load_state_dict(saved["state_dict"])
        forces = saved["forces_config"]
        return Trained(
            model.eval(),
            cfg,
            None if forces is None else ForcesConfig.model_validate(forces),
            None if saved["dt_s"] is None else float(saved["dt_s"]),
        )
