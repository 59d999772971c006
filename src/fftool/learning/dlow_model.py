"""The DLow sampler as functions: AgentFormer's per-benchmark settings, one training step over a frozen CVAE,
validation, and loading a trained sampler from its artifact alone.

Shared by the `dlow` stage (training) and `evaluate`, `predict` and the API (drawing), which never import
each other.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Literal

import torch

from fftool.artifacts.schema import DLOW_MODEL_FILE
from fftool.artifacts.store import Artifact
from fftool.config import CVAEConfig, DLowConfig
from fftool.learning.cvae_model import Trained, autocast
from fftool.learning.features import Prepared, decoder_features
from fftool.learning.training import model_file
from fftool.models.dlow import DLowLossParts, QNet, dlow_loss


@dataclass(frozen=True)
class Preset:
    """What AgentFormer's DLow configs set per dataset (its cfg/eth_ucy/<dataset>_agentformer.yml)."""

    diverse_weight: float
    d_scale: float
    schedule: Literal["step", "linear"]
    traj_scale: float  # AgentFormer divides positions by this (eth: 2); DLow's loss is computed in those units


AGENTFORMER: Final[dict[str, Preset]] = {
    "eth": Preset(20.0, 10.0, "step", 2.0),
    "hotel": Preset(5.0, 5.0, "step", 1.0),
    "univ": Preset(10.0, 10.0, "step", 1.0),
    "zara1": Preset(5.0, 5.0, "linear", 1.0),
    "zara2": Preset(5.0, 5.0, "step", 1.0),
}


def preset(benchmark: str) -> Preset:
    """AgentFormer's diversity weight and scale, schedule and units for `benchmark` (a dataset of one's own
    takes zara1's)."""
    return AGENTFORMER.get(benchmark, AGENTFORMER["zara1"])


def build_sampler(cvae_cfg: CVAEConfig, cfg: DLowConfig) -> QNet:
    return QNet(cvae_cfg.d_model, cvae_cfg.z_dim, cfg.k, cfg.qnet_hidden)


def training_loss(
    trained: Trained,
    sampler: QNet,
    prepared: Prepared,
    cfg: DLowConfig,
    chosen: Preset,
    gen: torch.Generator,
) -> DLowLossParts:
    """DLow's loss for one batch: the frozen CVAE (eval mode, no gradient of its own) encodes the past, the
    sampler's K codes are decoded with gradients flowing back to the codes only."""
    model, cvae_cfg = trained.model, trained.config
    with autocast(cvae_cfg, prepared.past.device):
        with torch.no_grad():
            tokens, agent_context = model.encode_past(prepared.past, prepared.agent_mask)
            prior = model.prior(agent_context)
        codes = sampler(agent_context)
        z = codes.z(cfg.train_w_mean, gen, cfg.share_eps).transpose(1, 2)  # (B, K, A, Z)
        k, steps = cfg.k, prepared.future_pos.shape[2]
        features = decoder_features(cvae_cfg.variant, prepared, trained.forces_config, trained.dt_s, repeat=k)
        samples = model.decode_k(
            z.reshape(-1, *z.shape[2:]),
            tokens,
            prepared.agent_mask,
            prepared.past_pos[:, :, -1],
            prepared.last_step,
            steps,
            features,
            k,
            goal=prepared.goal,
        )
    scale = chosen.traj_scale
    return dlow_loss(
        samples / scale,
        prepared.future_pos / scale,
        codes,
        prior,
        prepared.agent_mask,
        recon_weight=cfg.recon_weight,
        diverse_weight=chosen.diverse_weight,
        d_scale=chosen.d_scale,
        kl_weight=cfg.kl_weight,
        kl_min=cfg.kl_min,
    )


def load_sampler(dlow: Artifact, device: torch.device) -> QNet:
    """Rebuild a trained DLow sampler from its artifact alone (a damaged file is an IntegrityError)."""
    with model_file(dlow.file(DLOW_MODEL_FILE), device, "fftool train-dlow --force") as saved:
        sampler = QNet(saved["d_model"], saved["z_dim"], saved["k"], tuple(saved["hidden"])).to(device)
        sampler.load_state_dict(saved["state_dict"])
        return sampler.eval()
