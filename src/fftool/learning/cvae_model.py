"""A trained CVAE as the later stages see it: rebuild it from its artifact alone and draw K futures.

Shared by the `cvae` stage (validation), `evaluate` and `plot`, which never import each other.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from fftool.artifacts.schema import CVAE_MODEL_FILE
from fftool.artifacts.store import Artifact
from fftool.config import CVAEConfig, ForcesConfig
from fftool.learning.features import DECODER_DIMS, FEATURE_DIMS, Prepared, decoder_features
from fftool.learning.training import model_file
from fftool.models.forceformer import ForceFormer, Gaussian


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
    context: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> torch.Tensor:
    """K futures per agent from the prior: (B, K, A, Tf, 2) in the normalised frame."""
    B, A, Tf, _ = prepared.future_pos.shape
    with autocast(cfg, prepared.past.device):
        tokens, agent_context = context or model.encode_past(prepared.past, prepared.agent_mask)
        prior = model.prior(agent_context)
        rep = lambda x: x.repeat_interleave(k, 0)  # noqa: E731
        z = Gaussian(rep(prior.mu), rep(prior.logvar)).sample(generator_)
        features = decoder_features(cfg.variant, prepared, forces_cfg, dt_s, repeat=k)
        last = rep(prepared.past_pos[:, :, -1])
        out = model.decode(
            z, last, tokens, rep(prepared.agent_mask), Tf, features, repeat=k, last_step=rep(prepared.last_step)
        )
    return out.view(B, k, A, Tf, 2)


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
