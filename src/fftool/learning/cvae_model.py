"""The CVAE as functions: build it, its training loss and epoch plan, validation, drawing K futures, and
loading a trained one from its artifact alone.

Shared by the `cvae` stage (training, validation), `evaluate` and `plot`, which never import each other.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import NamedTuple

import numpy as np
import torch

from fftool.artifacts.schema import CVAE_MODEL_FILE
from fftool.artifacts.store import Artifact
from fftool.config import CVAEConfig, ForcesConfig
from fftool.learning.batches import SceneBatch, SceneSet
from fftool.learning.features import Prepared, decoder_features, prepare
from fftool.learning.protocols import repeat_windows, with_forces
from fftool.learning.training import epoch_batches, generator, model_file, validation_subset
from fftool.models.dlow import QNet
from fftool.models.forceformer import ForceFormer, Gaussian, LossParts, kl_divergence
from fftool.science.metrics import ade_fde
from fftool.variants import SPECS


def build_model(cfg: CVAEConfig) -> ForceFormer:
    model = ForceFormer(
        input_dim=SPECS[cfg.variant].feature_dim,
        decoder_dim=SPECS[cfg.variant].decoder_dim,
        d_model=cfg.d_model,
        n_heads=cfg.n_heads,
        d_ff=cfg.d_ff,
        dropout=cfg.dropout,
        n_layers=cfg.n_layers,
        z_dim=cfg.z_dim,
        output=cfg.output,
        relaxation_steps=cfg.relaxation_steps,
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
    sampler: QNet | None = None,
    pick: torch.Tensor | None = None,
    with_mean: bool = False,
    noise: torch.Tensor | None = None,
) -> torch.Tensor:
    """K futures per agent, (B, K, A, Tf, 2) in the normalised frame: drawn from the prior, or, given a DLow
    `sampler`, decoded from its K codes z = b (AgentFormer's test-time codes). `pick` (B,): each window
    decodes only one code (the fair protocol's windows, one per goal), so K is 1: the sampler's code `pick`
    (a prior draw without a sampler), or the prior's mean where `pick` is -1. with_mean: the prior's mean code
    decoded in the same rollout as one more sample, last (`most_likely`'s future at the cost of a few more
    tokens instead of a second rollout); the draws are those without it. noise: the standard normal draws of the
    prior's codes, (B · K, A, Z) window-major (under `pick`, one per window, zero where the window decodes the
    mean), instead of generator_'s."""
    with autocast(cfg, prepared.past.device):
        tokens, agent_context = model.encode_past(prepared.past, prepared.agent_mask)
        prior = model.prior(agent_context)
        B, A, Z = prior.mu.shape
        if pick is not None:  # one code per window
            mean_rows = pick < 0
            if sampler is None:
                if noise is None:  # the generator's draws for the windows that draw, in order; none for the mean's
                    noise = torch.zeros_like(prior.mu)
                    noise[~mean_rows] = torch.randn(noise[~mean_rows].shape, generator=generator_, device=noise.device)
                z = prior.sample(noise=noise)  # μ itself where the noise is zero
            else:
                codes = sampler(agent_context).b  # (B, A, K', Z)
                picked = codes[torch.arange(B, device=codes.device), :, pick.clamp_min(0)]
                z = torch.where(mean_rows[:, None, None], prior.mu.to(picked.dtype), picked)
            z = z[:, None]  # (B, 1, A, Z)
        elif sampler is None:
            rep = lambda x: x.repeat_interleave(k, 0)  # noqa: E731
            z = Gaussian(rep(prior.mu), rep(prior.logvar)).sample(generator_, noise).view(B, k, A, Z)
        else:
            codes = sampler(agent_context).b  # (B, A, K', Z)
            if codes.shape[2] != k:
                raise ValueError(f"the DLow sampler draws {codes.shape[2]} futures per agent, {k} were asked for")
            z = codes.transpose(1, 2)  # (B, K, A, Z)
        if with_mean:
            z = torch.cat([z, prior.mu[:, None].to(z.dtype)], 1)
        return _decode_codes(model, prepared, cfg, forces_cfg, dt_s, tokens, z)


def most_likely(
    model: ForceFormer, prepared: Prepared, cfg: CVAEConfig, forces_cfg: ForcesConfig | None, dt_s: float | None
) -> torch.Tensor:
    """One future per agent, (B, 1, A, Tf, 2) in the normalised frame: decoded from the prior's mean code
    (z = μ of p(z | past)), the centre of the distribution the K samples are drawn from. Deterministic."""
    with autocast(cfg, prepared.past.device):
        tokens, agent_context = model.encode_past(prepared.past, prepared.agent_mask)
        return _decode_codes(model, prepared, cfg, forces_cfg, dt_s, tokens, model.prior(agent_context).mu[:, None])


def _decode_codes(
    model: ForceFormer,
    prepared: Prepared,
    cfg: CVAEConfig,
    forces_cfg: ForcesConfig | None,
    dt_s: float | None,
    tokens: torch.Tensor,
    z: torch.Tensor,
) -> torch.Tensor:
    """The futures (B, K, A, Tf, 2) of codes z (B, K, A, Z), all K from each window's encoded past `tokens`."""
    B, k, A, Z = z.shape
    steps = prepared.future_pos.shape[2]
    where = (prepared.agent_mask, prepared.past_pos[:, :, -1], prepared.last_step, steps)
    features = decoder_features(cfg.variant, prepared, forces_cfg, dt_s, repeat=k)
    return model.decode_k(z.reshape(B * k, A, Z), tokens, *where, features, k, goal=prepared.goal)


def epoch_plan(
    train: SceneSet, cfg: CVAEConfig, epoch: int, n_windows: int
) -> tuple[list[np.ndarray], np.random.Generator]:
    """The batches of one epoch (seeded by (seed, epoch)) and the generator that goes on to draw agent caps,
    each batch planned by the agents it will carry (at most cfg.max_agents per window)."""
    return epoch_batches(train, cfg.seed, epoch, n_windows, cfg.batch_windows, cfg.max_agent_pairs, cfg.max_agents)


def training_loss(
    net: torch.nn.Module,
    prepared: Prepared,
    cfg: CVAEConfig,
    forces_cfg: ForcesConfig | None,
    dt_s: float | None,
    gen: torch.Generator,
    best_of_k: bool = True,
) -> LossParts:
    """AgentFormer's loss parts for one batch (posterior reconstruction, KL, best-of-train_k, or without the
    last when `best_of_k` is False): the model's forward, called through `net` (the model, or the model in
    DistributedDataParallel)."""
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
            cfg.train_k if best_of_k else 0,
            cfg.kl_min,
            gen,
            goal=prepared.goal,
        )


def fair_best_of_k(
    model: ForceFormer,
    batch: SceneBatch,
    goal_sets: torch.Tensor,
    cfg: CVAEConfig,
    forces_cfg: ForcesConfig | None,
    dt_s: float | None,
    obs_len: int,
    gen: torch.Generator,
) -> torch.Tensor:
    """The best-of-K term under the fair protocol, as `cvae_loss` averages its own: sample k decodes goal k of
    goal_sets (B, A, K, 2, world), each window encoded once per goal (as `evaluate` does), one prior draw each;
    the squared error summed over steps and xy, min over the K per agent, mean over each window's agents, then
    over the windows with an agent.

    Each copy is turned by its own random scene rotation; the errors do not depend on the frame."""
    B, A, k = goal_sets.shape[:3]
    copies = repeat_windows(batch, k)
    goal = goal_sets.transpose(1, 2).reshape(B * k, A, 2)  # window-major, as repeat_windows orders the copies
    if forces_cfg is not None and dt_s is not None:
        copies = with_forces(copies, goal, forces_cfg, dt_s, obs_len, SPECS[cfg.variant].training_reads)
    prepared = prepare(copies, cfg.variant, obs_len, goal=goal, rotate=cfg.rotate, generator=gen)
    futures = sample(model, prepared, cfg, forces_cfg, dt_s, 1, gen)[:, 0]  # (B·k, A, T, 2)
    error = ((futures.float() - prepared.future_pos) ** 2).sum((-1, -2)).view(B, k, A)
    mask = batch.agent_mask
    per_window = (error.min(1).values * mask).sum(1) / mask.sum(1).clamp_min(1)
    real = mask.any(1)
    return (per_window * real).sum() / real.sum().clamp_min(1)


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


@torch.no_grad()
def validate(
    model: ForceFormer,
    scenes: SceneSet,
    windows: np.ndarray,
    cfg: CVAEConfig,
    forces_cfg: ForcesConfig | None,
    dt_s: float | None,
    obs_len: int,
    device: torch.device,
) -> dict[str, float]:
    """The model's validation minADE_K / minFDE_K with K = cfg.k prior samples (`min_ade`, `min_fde`), and,
    from the same pass, whether the latent carries the future (means over agents, metres):

    posterior_mean_ade/fde: the future decoded from q(z | X, Y)'s mean, against cv_ade/fde, constant velocity on
    the same agents (a latent that carries the future decodes better than a straight line); kl_unclamped: the
    KL(q ‖ p) per agent before the free-bits clamp; prior_spread_m: the RMS distance of the K prior samples'
    final points from their mean; z_sensitivity_m: how far the final point moves for one unit of z (the
    prior's mean against the mean plus a fixed random unit vector per agent).
    """
    model.eval()
    gen, unit_gen = generator(cfg.seed, device), generator(cfg.seed + 1, device)
    names = ("min_ade", "min_fde", "posterior_mean_ade", "posterior_mean_fde", "cv_ade", "cv_fde", "kl_unclamped")
    sums = dict.fromkeys((*names, "prior_spread_m", "z_sensitivity_m"), 0.0)
    count = 0
    for members in scenes.plan(windows, cfg.batch_windows, cfg.max_agent_pairs, np.random.default_rng(0)):
        prepared = prepare(scenes.batch(members).to(device), cfg.variant, obs_len)
        mask, steps = prepared.agent_mask, prepared.future_pos.shape[2]
        samples = sample(model, prepared, cfg, forces_cfg, dt_s, cfg.k, gen)  # (B, K, A, T, 2)
        features = decoder_features(cfg.variant, prepared, forces_cfg, dt_s)
        with autocast(cfg, device):
            tokens, agent_context = model.encode_past(prepared.past, mask)
            q, p = model.posterior(prepared.future, tokens, mask), model.prior(agent_context)
            last, last_step = prepared.past_pos[:, :, -1], prepared.last_step
            decode = partial(model.decode, last_pos=last, context=tokens, agent_mask=mask, steps=steps,
                             features=features, last_step=last_step, goal=prepared.goal)  # fmt: skip
            mean_q = decode(q.mu)[:, None]  # (B, 1, A, T, 2)
            unit = torch.randn(p.mu.shape, generator=unit_gen, device=device)
            moved = (decode(p.mu + unit / unit.norm(dim=-1, keepdim=True)) - decode(p.mu))[:, :, -1].norm(dim=-1)
        steps_ahead = torch.arange(1, steps + 1, device=device, dtype=torch.float32)[None, None, :, None]
        cv = (prepared.past_pos[:, :, -1:] + steps_ahead * prepared.last_step[:, :, None])[:, None]
        finals = samples[:, :, :, -1]  # (B, K, A, 2)
        spread = ((finals - finals.mean(1, keepdim=True)) ** 2).sum(-1).mean(1)  # (B, A) mean squared distance
        sample_ade, sample_fde = ade_fde(samples, prepared.future_pos)  # (B, K, A)
        per_agent = {
            "min_ade": sample_ade.min(1).values,
            "min_fde": sample_fde.min(1).values,
            "kl_unclamped": kl_divergence(q, p),
            "prior_spread_m": spread,
            "z_sensitivity_m": moved,
        }
        for name, (ade, fde) in (("posterior_mean", ade_fde(mean_q, prepared.future_pos)),
                                 ("cv", ade_fde(cv, prepared.future_pos))):  # fmt: skip
            per_agent |= {f"{name}_ade": ade[:, 0], f"{name}_fde": fde[:, 0]}
        for name, values in per_agent.items():
            sums[name] += float((values * mask).sum())
        count += int(mask.sum())
    means = {name: value / max(count, 1) for name, value in sums.items()}
    means["prior_spread_m"] = means["prior_spread_m"] ** 0.5  # RMS
    return means


def val_windows(scenes: SceneSet, cfg: CVAEConfig) -> np.ndarray:
    """The fixed validation subset: `val_max_windows` windows drawn with the run's seed (all if 0)."""
    return validation_subset(scenes.windows, cfg.val_max_windows, cfg.seed)


class Trained(NamedTuple):
    model: ForceFormer  # in eval mode
    config: CVAEConfig
    forces_config: ForcesConfig | None  # the force constants it decodes with (None: a variant without forces)
    dt_s: float | None  # the time step its forces were computed with


def scale_output(trained: Trained, factor: float) -> Trained:
    """The model with its decoder's output head times `factor`, in place: 0 leaves only the path the output is a
    residual over (`forceformer.output_base`), with no network, to measure what the network adds to it."""
    with torch.no_grad():
        for parameter in trained.model.out.parameters():  # W·x + b, so the whole learned output
            parameter.mul_(factor)
    return trained


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
