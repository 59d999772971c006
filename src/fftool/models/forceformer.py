"""AgentFormer's CVAE (Yuan et al., ICCV 2021) with ForceFormer's input variants, batched with padding.

encode past (X-encoder) → posterior q(z|X,Y) (Y-encoder) / prior p(z|X) → decode autoregressively.
Letters: B windows, A agent slots, T steps, D model width; a scene is flattened time-major into
T·A tokens (token t·A + a). Padded agent slots are masked out of every attention and every loss, so
adding padding changes nothing for the real agents. research/agentformer.md has the reference details.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal, NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn


class Keys(NamedTuple):
    """Projected keys of an attention, laid out once for the products that read them (a decoding step reads a
    memory's keys and the cached keys of earlier steps at every step, so no step copies them again):
    k and v (B, H, Lk, d_head), contiguous; k_self by agent and transposed, (B, H, A, d_head, Tk)."""

    k: Tensor
    k_self: Tensor
    v: Tensor

    def extend(self, other: Keys) -> Keys:
        return Keys(torch.cat([self.k, other.k], 2), torch.cat([self.k_self, other.k_self], 4),
                    torch.cat([self.v, other.v], 2))  # fmt: skip


class Queries(NamedTuple):
    """Projected, pre-scaled queries: q and q_self, each (B, H, Lq, d_head)."""

    q: Tensor
    q_self: Tensor


class KeyCache:
    """The self-attention keys of the steps decoded so far.

    Without autograd the keys are written into buffers allocated once per rollout (no copying of the
    prefix at every step); with autograd they are concatenated, since in-place writes would invalidate
    the views that earlier steps saved for the backward pass.
    """

    def __init__(self, steps: int) -> None:
        self.capacity, self.length = steps, 0  # in steps
        self.keys: Keys | None = None

    def append(self, new: Keys) -> Keys:
        if torch.is_grad_enabled() or torch.compiler.is_exporting():  # an exported graph concatenates too
            self.keys = new if self.keys is None else self.keys.extend(new)
            self.length += new.k_self.shape[4]
            return self.keys
        if self.keys is None:
            (B, H, agents, dh, _), cap = new.k_self.shape, self.capacity
            self.keys = Keys(new.k.new_empty(B, H, cap * agents, dh), new.k.new_empty(B, H, agents, dh, cap),
                             new.k.new_empty(B, H, cap * agents, dh))  # fmt: skip
        agents, steps = new.k_self.shape[2], new.k_self.shape[4]
        tokens = slice(self.length * agents, (self.length + steps) * agents)
        self.keys.k[:, :, tokens] = new.k
        self.keys.k_self[..., self.length : self.length + steps] = new.k_self
        self.keys.v[:, :, tokens] = new.v
        self.length += steps
        return Keys(self.keys.k[:, :, : self.length * agents], self.keys.k_self[..., : self.length],
                    self.keys.v[:, :, : self.length * agents])  # fmt: skip


class Dropout(nn.Dropout):
    """nn.Dropout whose CPU masks take 16 random bits per element, four elements per 64-bit draw.

    torch's CPU bernoulli makes one generator call per element, which was a fifth of a training step
    (profiled in docs/cvae.md). Here P(drop) = round(p · 2¹⁶) / 2¹⁶ (within 8e-6 of p) and kept
    values are scaled by 1 / (1 - that); masks come from torch's global generator, so seeded runs repeat.
    Other devices keep torch's fused kernel.
    """

    def forward(self, x: Tensor) -> Tensor:
        if not self.training or self.p == 0:
            return x  # as nn.Dropout returns it, without the call (a sampling step makes dozens)
        if x.device.type != "cpu":
            return super().forward(x)
        dropped = round(self.p * 65536)
        n = x.numel()
        words = torch.empty((n + 3) // 4, dtype=torch.int64).random_(-(2**63), 2**63 - 1)
        bits = words.view(torch.int16)[:n].view(x.shape)  # uniform on [-2¹⁵, 2¹⁵)
        keep = (bits >= dropped - 32768).to(x.dtype).mul_(65536 / (65536 - dropped))
        return x * keep


class AgentAwareAttention(nn.Module):
    """Multi-head attention with separate query/key projections for same-agent token pairs.

    score(i, j) = q_self_i · k_self_j if tokens i and j belong to the same agent, else q_i · k_j
    (both / sqrt(d_head)); values and output projection are shared (AgentFormer §3.2).
    """

    def __init__(self, d_model: int, n_heads: int, dropout: float) -> None:
        super().__init__()
        assert d_model % n_heads == 0, f"d_model {d_model} must be divisible by n_heads {n_heads}"
        self.n_heads, self.d_head = n_heads, d_model // n_heads
        self.q, self.k, self.v = (nn.Linear(d_model, d_model) for _ in range(3))
        self.q_self, self.k_self = nn.Linear(d_model, d_model), nn.Linear(d_model, d_model)
        self.out = nn.Linear(d_model, d_model)
        self.dropout = Dropout(dropout)
        self._stacked: dict[tuple, tuple] = {}  # _fused: per layer set, the parameter versions and their stacks
        for layer in (self.q, self.k, self.v, self.q_self, self.k_self):
            nn.init.xavier_uniform_(layer.weight)
            nn.init.zeros_(layer.bias)
        nn.init.zeros_(self.out.bias)

    def _heads(self, x: Tensor) -> Tensor:
        B, L, D = x.shape
        return x.view(B, L, self.n_heads, self.d_head).transpose(1, 2)  # (B, H, L, dh)

    def _project(self, x: Tensor, layers: tuple[nn.Linear, ...]) -> list[Tensor]:
        """Several projections of x as one matrix product (much faster than one small product each); the
        query projections come out scaled by 1/sqrt(d_head) (`_fused`)."""
        weight, bias = self._fused(layers)
        return [self._heads(part) for part in F.linear(x, weight, bias).chunk(len(layers), -1)]

    def _fused(self, layers: tuple[nn.Linear, ...]) -> tuple[Tensor, Tensor]:
        """The layers' weights and biases stacked, the query layers' scaled by 1/sqrt(d_head) (scaling the
        weights instead of every query; exact for a power-of-two d_head); without autograd kept until a
        parameter changes (sampling projects the same layers at every decoding step), with it stacked afresh
        so gradients flow."""
        parameters = [p for layer in layers for p in (layer.weight, layer.bias)]
        if torch.is_grad_enabled() or torch.compiler.is_exporting():  # an exported graph holds the stacks itself
            return self._stack(layers)
        which, versions = tuple(map(id, layers)), tuple((p.data_ptr(), p._version) for p in parameters)
        kept = self._stacked.get(which)
        if kept is None or kept[0] != versions:
            kept = self._stacked[which] = (versions, *self._stack(layers))
        return kept[1], kept[2]

    def _stack(self, layers: tuple[nn.Linear, ...]) -> tuple[Tensor, Tensor]:
        scale = 1 / math.sqrt(self.d_head)
        scales = [scale if layer is self.q or layer is self.q_self else 1.0 for layer in layers]
        weight = torch.cat([layer.weight * s if s != 1 else layer.weight for layer, s in zip(layers, scales)])
        bias = torch.cat([layer.bias * s if s != 1 else layer.bias for layer, s in zip(layers, scales)])
        return weight, bias

    @staticmethod
    def _laid_out(k: Tensor, k_self: Tensor, v: Tensor, agents: int) -> Keys:
        """Keys as `Keys` holds them: k and v contiguous, k_self by agent and transposed."""
        B, H, Lk, dh = k_self.shape
        by_agent = k_self.reshape(B, H, Lk // agents, agents, dh).permute(0, 1, 3, 4, 2).contiguous()
        return Keys(k.contiguous(), by_agent, v.contiguous())

    def keys(self, key: Tensor, agents: int) -> Keys:
        """Project key tokens (B, Lk, D) of `agents` slots once; decoders keep these instead of re-projecting
        (and re-laying out) a memory at every step."""
        return self._laid_out(*self._project(key, (self.k, self.k_self, self.v)), agents)

    def queries(self, query: Tensor) -> Queries:
        """Project query tokens (B, Lq, D), pre-scaled by 1/sqrt(d_head) (cheaper than scaling scores)."""
        return Queries(*self._project(query, (self.q, self.q_self)))

    def project(self, x: Tensor, agents: int) -> tuple[Queries, Keys]:
        """Queries and keys of the same tokens (self-attention) in one product."""
        q, q_self, k, k_self, v = self._project(x, (self.q, self.q_self, self.k, self.k_self, self.v))
        return Queries(q, q_self), self._laid_out(k, k_self, v, agents)

    def attend(self, queries: Queries, keys: Keys, agents: int, allowed: Tensor | None) -> Tensor:
        """Projected queries and keys in time-major layouts of `agents` slots; allowed (B, Lq, Lk) bool,
        None when every pair is allowed (no padding in the batch: masking would change nothing).

        Same-agent scores are needed only where query and key belong to the same agent (1/A of the
        pairs), so they are computed per agent alone and written over the shared scores.
        """
        B, H, Lq, dh = queries.q.shape
        Lk = keys.k.shape[2]
        scores = queries.q @ keys.k.transpose(-1, -2)  # (B, H, Lq, Lk)
        by_agent = queries.q_self.reshape(B, H, Lq // agents, agents, dh).transpose(2, 3)  # (B, H, A, Tq, dh)
        own = (by_agent @ keys.k_self).permute(0, 1, 3, 4, 2)  # (B, H, Tq, Tk, A)
        if torch.compiler.is_exporting():  # an exported graph is functional: the same scores without in-place writes
            # scattered into the flattened (A, Tk, A) block of each query step: entry (a, t, a) is a·Tk·A + t·A + a
            Tq, Tk = Lq // agents, Lk // agents
            a, t = torch.arange(agents, device=scores.device), torch.arange(Tk, device=scores.device)
            index = (a[:, None] * (Tk * agents + 1) + t[None, :] * agents).reshape(1, 1, 1, -1)  # (1, 1, 1, A·Tk)
            updates = own.permute(0, 1, 2, 4, 3).reshape(B, H, Tq, agents * Tk)
            block = scores.reshape(B, H, Tq, agents * Tk * agents)
            scores = block.scatter(-1, index.expand(B, H, Tq, -1), updates).reshape(B, H, Lq, Lk)
            if allowed is not None:
                scores = scores.masked_fill(~allowed[:, None], float("-inf"))
        else:
            grid = scores.view(B, H, Lq // agents, agents, Lk // agents, agents)
            torch.diagonal(grid, dim1=3, dim2=5).copy_(own)
            if allowed is not None:
                scores.masked_fill_(~allowed[:, None], float("-inf"))  # in place: no copy of the scores
        weights = self.dropout(torch.softmax(scores, dim=-1))
        mixed = (weights @ keys.v).transpose(1, 2).flatten(2)  # (B, Lq, D)
        return self.out(mixed)

    def forward(self, query: Tensor, key: Tensor, agents: int, allowed: Tensor | None) -> Tensor:
        """query (B, Lq, D), key (B, Lk, D), both time-major over `agents` slots; allowed (B, Lq, Lk)."""
        if query is key:
            return self.attend(*self.project(query, agents), agents, allowed)
        return self.attend(self.queries(query), self.keys(key, agents), agents, allowed)


class _FeedForward(nn.Sequential):
    def __init__(self, d_model: int, d_ff: int, dropout: float) -> None:
        super().__init__(nn.Linear(d_model, d_ff), nn.ReLU(), Dropout(dropout), nn.Linear(d_ff, d_model))


class EncoderLayer(nn.Module):
    """Post-LN transformer encoder layer with agent-aware self-attention."""

    def __init__(self, d_model: int, n_heads: int, d_ff: int, dropout: float) -> None:
        super().__init__()
        self.attn = AgentAwareAttention(d_model, n_heads, dropout)
        self.ff = _FeedForward(d_model, d_ff, dropout)
        self.norm1, self.norm2 = nn.LayerNorm(d_model), nn.LayerNorm(d_model)
        self.drop = Dropout(dropout)

    def forward(self, x: Tensor, agents: int, allowed: Tensor | None) -> Tensor:
        x = self.norm1(x + self.drop(self.attn(x, x, agents, allowed)))
        return self.norm2(x + self.drop(self.ff(x)))


class DecoderLayer(nn.Module):
    """Post-LN decoder layer: agent-aware self-attention, then agent-aware cross-attention to a memory."""

    def __init__(self, d_model: int, n_heads: int, d_ff: int, dropout: float) -> None:
        super().__init__()
        self.self_attn = AgentAwareAttention(d_model, n_heads, dropout)
        self.cross_attn = AgentAwareAttention(d_model, n_heads, dropout)
        self.ff = _FeedForward(d_model, d_ff, dropout)
        self.norms = nn.ModuleList(nn.LayerNorm(d_model) for _ in range(3))
        self.drop = Dropout(dropout)

    def forward(
        self,
        x: Tensor,
        memory: Tensor | Keys,
        agents: int,
        masks: tuple[Tensor | None, Tensor | None],
        self_keys: tuple[Queries, Keys] | None = None,
        fold: int = 1,
    ) -> Tensor:
        """memory: tokens or their projected keys; self_keys: x's projected queries with the cached keys of
        the earlier steps and x; masks: allowed pairs of the self- and the cross-attention.

        fold: x holds `fold` samples per memory window (repeat_interleave order); the cross-attention
        then reads them as one longer query of that window, so the memory is never copied per sample
        (allowed_cross is (B / fold, fold · Lq, Lk)).
        """
        allowed_self, allowed_cross = masks
        queries, keys = self.self_attn.project(x, agents) if self_keys is None else self_keys
        memory_keys = memory if isinstance(memory, Keys) else self.cross_attn.keys(memory, agents)
        x = self.norms[0](x + self.drop(self.self_attn.attend(queries, keys, agents, allowed_self)))
        B, L, D = x.shape
        folded = self.cross_attn.queries(x.reshape(B // fold, fold * L, D))
        crossed = self.cross_attn.attend(folded, memory_keys, agents, allowed_cross)
        x = self.norms[1](x + self.drop(crossed.reshape(B, L, D)))
        return self.norms[2](x + self.drop(self.ff(x)))


class TimeEmbedding(nn.Module):
    """Linear(features) concatenated with a sinusoidal encoding of the step, projected back to D."""

    def __init__(self, in_dim: int, d_model: int, dropout: float) -> None:
        super().__init__()
        self.inp = nn.Linear(in_dim, d_model)
        self.proj = nn.Linear(2 * d_model, d_model)
        self.drop = Dropout(dropout)
        self.d_model = d_model

    def encoding(self, steps: Tensor) -> Tensor:
        """(T,) step indices -> (T, D) sin on even, cos on odd dims, base 10000."""
        div = torch.exp(torch.arange(0, self.d_model, 2, device=steps.device) * (-math.log(10000.0) / self.d_model))
        angle = steps[:, None].float() * div[None]
        return torch.stack([torch.sin(angle), torch.cos(angle)], -1).flatten(1)[:, : self.d_model]

    def forward(self, x: Tensor, first_step: int = 0) -> Tensor:
        """x (B, A, T, F) -> tokens (B, T·A, D), time-major; steps numbered from first_step."""
        B, A, T, _ = x.shape
        steps = torch.arange(first_step, first_step + T, device=x.device)
        h = self.inp(x)  # (B, A, T, D)
        pe = self.encoding(steps)[None, None].expand(B, A, T, -1)
        h = self.drop(self.proj(torch.cat([h, pe], -1)))
        return h.transpose(1, 2).reshape(B, T * A, -1)


def _token_masks(agent_mask: Tensor, t_query: int, t_key: int, causal: bool) -> Tensor | None:
    """Allowed query-key pairs (B, Lq, Lk) for time-major token layouts; None when every pair is allowed.

    Keys of padded agents are never allowed; every query may see itself, so no softmax row is empty
    (padded queries see only themselves). With `causal`, a token at step s sees steps <= s of everyone.
    """
    if not causal and not torch.compiler.is_exporting() and bool(agent_mask.all()):
        return None  # no padding: masking would change nothing (an exported graph masks always: no data branch)
    B, A = agent_mask.shape
    allowed = agent_mask.repeat(1, t_key)[:, None, :].expand(B, t_query * A, t_key * A)
    if causal:
        q_step = torch.arange(t_query * A, device=agent_mask.device) // A
        k_step = torch.arange(t_key * A, device=agent_mask.device) // A
        allowed = allowed & (k_step[None, :] <= q_step[:, None])
    if t_query == t_key:
        allowed = allowed | torch.eye(t_query * A, dtype=torch.bool, device=agent_mask.device)
    return allowed


class Gaussian(NamedTuple):
    mu: Tensor  # (B, A, Z)
    logvar: Tensor  # (B, A, Z)

    def sample(self, generator: torch.Generator | None = None, noise: Tensor | None = None) -> Tensor:
        """A draw mu + std · noise; noise: standard normal draws of mu's shape to use instead of the generator's
        (an exported graph takes them as an input)."""
        if noise is None:
            noise = torch.randn(self.mu.shape, generator=generator, device=self.mu.device, dtype=self.mu.dtype)
        return self.mu + noise * torch.exp(0.5 * self.logvar)


def kl_divergence(q: Gaussian, p: Gaussian) -> Tensor:
    """KL(q || p) per agent, summed over latent dims: (B, A)."""
    var_q, var_p = q.logvar.exp(), p.logvar.exp() + 1e-8
    return 0.5 * (torch.log(var_p) - q.logvar + (var_q + (q.mu - p.mu) ** 2) / var_p - 1).sum(-1)


StepFeatures = Callable[[Tensor, int], Tensor]
"""(positions so far (B, A, s, 2) incl. the last observed, step index s - 1) -> decoder features (B, A, F)."""

OutputType = Literal["offset", "cv_residual", "goal_residual", "relaxation_residual"]
"""What the decoder's 2-vector at step s means (docs/cvae.md, "Output parametrisation"):
offset: position - last observed position (AgentFormer's sn_out_type 'norm', its zara1 default);
cv_residual: position - the constant-velocity extrapolation of the last observed step (fftool's option);
goal_residual: position - the constant-acceleration curve that leaves the last observed position with the last
observed step and reaches the goal at the last predicted step (fftool's option, for variants that read a goal);
relaxation_residual: position - the path under the driving force alone (Helbing & Molnár): each step relaxes
from the last observed one toward a constant step w by λ = exp(-1 / relaxation_steps) per step, w the one that
reaches the goal at the last predicted step (fftool's option, for variants that read a goal).
"""


def output_base(
    output: str,
    step: int,
    steps: int,
    last_pos: Tensor,
    last_step: Tensor | None,
    goal: Tensor | None,
    relaxation_steps: float = 5.0,
) -> Tensor | None:
    """The path the output at step `step` (0-based, of `steps`) is a residual over, as an offset from the last
    observed position (B, A, 2); None for "offset". last_step: the last observed displacement; goal: the
    goal in the same frame (both (B, A, 2)); relaxation_steps: τ of "relaxation_residual", in time steps (0: the
    straight line to the goal at constant speed)."""
    if output == "offset":
        return None
    assert last_step is not None, f"output {output!r} needs the last observed step"
    ahead = step + 1
    if output == "cv_residual":
        return ahead * last_step
    assert goal is not None, f"output {output!r} needs the goal"
    if output == "goal_residual":
        acceleration = (goal - last_pos - steps * last_step) / steps**2
        return ahead * last_step + ahead**2 * acceleration
    lam = math.exp(-1.0 / relaxation_steps) if relaxation_steps > 0 else 0.0  # τ = 0: the straight line
    relaxed = lam * (1 - lam**ahead) / (1 - lam)  # Σ_{s ≤ ahead} λˢ: how much of the last step is left so far
    total = lam * (1 - lam**steps) / (1 - lam)
    desired = (goal - last_pos - total * last_step) / (steps - total)  # the constant step w that reaches the goal
    return ahead * desired + relaxed * (last_step - desired)


class ForceFormer(nn.Module):
    """The CVAE: X-encoder, Y-encoder (posterior), learned prior, autoregressive decoder."""

    def __init__(
        self,
        *,
        input_dim: int,
        decoder_dim: int,
        d_model: int = 256,
        n_heads: int = 8,
        d_ff: int = 512,
        dropout: float = 0.1,
        n_layers: int = 2,
        z_dim: int = 32,
        output: OutputType = "offset",
        relaxation_steps: float = 5.0,
        out_init_std: float = 0.01,
    ) -> None:
        super().__init__()
        self.z_dim, self.output, self.relaxation_steps = z_dim, output, relaxation_steps
        self.past_embed = TimeEmbedding(input_dim, d_model, dropout)
        self.future_embed = TimeEmbedding(input_dim, d_model, dropout)
        self.decoder_embed = TimeEmbedding(decoder_dim + z_dim, d_model, dropout)
        self.encoder = nn.ModuleList(EncoderLayer(d_model, n_heads, d_ff, dropout) for _ in range(n_layers))
        self.future_encoder = nn.ModuleList(DecoderLayer(d_model, n_heads, d_ff, dropout) for _ in range(n_layers))
        self.decoder = nn.ModuleList(DecoderLayer(d_model, n_heads, d_ff, dropout) for _ in range(n_layers))
        self.q_head, self.p_head = nn.Linear(d_model, 2 * z_dim), nn.Linear(d_model, 2 * z_dim)
        self.out = nn.Linear(d_model, 2)
        for head in (self.q_head, self.p_head):  # N(0, 0.01²), zero bias: prior ≈ N(0, I) at init
            nn.init.normal_(head.weight, std=0.01)
            nn.init.zeros_(head.bias)
        nn.init.normal_(self.out.weight, std=out_init_std)  # AgentFormer: 0.01
        nn.init.zeros_(self.out.bias)

    # --- encode -----------------------------------------------------------------------------------

    def encode_past(self, past: Tensor, agent_mask: Tensor) -> tuple[Tensor, Tensor]:
        """past (B, A, Tp, F) -> context tokens (B, Tp·A, D) and per-agent context (B, A, D)."""
        B, A, Tp, _ = past.shape
        x = self.past_embed(past)
        allowed = _token_masks(agent_mask, Tp, Tp, causal=False)
        for layer in self.encoder:
            x = layer(x, A, allowed)
        return x, x.view(B, Tp, A, -1).mean(1)

    def prior(self, agent_context: Tensor) -> Gaussian:
        return Gaussian(*self.p_head(agent_context).float().chunk(2, -1))  # float32 under autocast too

    def posterior(self, future: Tensor, context: Tensor, agent_mask: Tensor) -> Gaussian:
        """future (B, A, Tf, F) with the context -> q(z | X, Y)."""
        B, A, Tf, _ = future.shape
        Tp = context.shape[1] // A
        x = self.future_embed(future)
        masks = (_token_masks(agent_mask, Tf, Tf, causal=False), _token_masks(agent_mask, Tf, Tp, causal=False))
        for layer in self.future_encoder:
            x = layer(x, context, A, masks)
        return Gaussian(*self.q_head(x.view(B, Tf, A, -1).mean(1)).float().chunk(2, -1))

    # --- train ------------------------------------------------------------------------------------

    def forward(
        self,
        past: Tensor,
        future: Tensor,
        target: Tensor,
        agent_mask: Tensor,
        last_pos: Tensor,
        last_step: Tensor,
        features: StepFeatures,
        features_k: StepFeatures,
        k: int,
        kl_min: float,
        generator: torch.Generator | None = None,
        goal: Tensor | None = None,
    ) -> LossParts:
        """AgentFormer's training loss terms for one batch (so DistributedDataParallel wraps the model itself).

        past, future: (B, A, Tp|Tf, F) encoder and posterior features; target: (B, A, Tf, 2) the positions to
        predict; last_pos, last_step: (B, A, 2) the last observed position and displacement; features and
        features_k: the decoder's step features for one and for `k` samples per window (`decode`). k = 0 leaves
        the best-of-K term out (a warm-up on the posterior's reconstruction and the KL alone). The posterior draw
        comes first, then the k prior draws, from `generator`. goal (B, A, 2): for the goal outputs
        ("goal_residual", "relaxation_residual").
        """
        tokens, agent_context = self.encode_past(past, agent_mask)
        q = self.posterior(future, tokens, agent_mask)
        p = self.prior(agent_context)
        steps = target.shape[2]
        recon = self.decode(
            q.sample(generator), last_pos, tokens, agent_mask, steps, features, last_step=last_step, goal=goal
        )
        # The prior is applied once more for the samples: the same values, and the gradients then add up in the
        # order fftool's first trainings used, so their weights repeat bit for bit.
        samples = None
        if k:
            prior = self.prior(agent_context)
            samples = self.sample(
                prior, tokens, agent_mask, last_pos, last_step, steps, features_k, k, generator, goal=goal
            )
        return cvae_loss(recon, target, q, p, samples, agent_mask, kl_min)

    def sample(
        self,
        prior: Gaussian,
        context: Tensor,
        agent_mask: Tensor,
        last_pos: Tensor,
        last_step: Tensor,
        steps: int,
        features_k: StepFeatures,
        k: int,
        generator: torch.Generator | None = None,
        goal: Tensor | None = None,
    ) -> Tensor:
        """k futures per agent drawn from `prior`: (B, k, A, steps, 2), the context shared by the k samples."""
        rep = lambda x: x.repeat_interleave(k, 0)  # noqa: E731
        z = Gaussian(rep(prior.mu), rep(prior.logvar)).sample(generator)
        return self.decode_k(z, context, agent_mask, last_pos, last_step, steps, features_k, k, goal=goal)

    def decode_k(
        self,
        z: Tensor,
        context: Tensor,
        agent_mask: Tensor,
        last_pos: Tensor,
        last_step: Tensor,
        steps: int,
        features_k: StepFeatures,
        k: int,
        goal: Tensor | None = None,
    ) -> Tensor:
        """The futures (B, k, A, steps, 2) of the codes z (B·k, A, Z), window-major (repeat_interleave order);
        goal (B, A, 2) shared by a window's k samples."""
        B, A, _ = last_pos.shape
        rep = lambda x: x.repeat_interleave(k, 0)  # noqa: E731
        out = self.decode(
            z,
            rep(last_pos),
            context,
            rep(agent_mask),
            steps,
            features_k,
            repeat=k,
            last_step=rep(last_step),
            goal=None if goal is None else rep(goal),
        )
        return out.view(B, k, A, steps, 2)

    # --- decode -----------------------------------------------------------------------------------

    def decode(
        self,
        z: Tensor,
        last_pos: Tensor,
        context: Tensor,
        agent_mask: Tensor,
        steps: int,
        features: StepFeatures,
        repeat: int = 1,
        last_step: Tensor | None = None,
        goal: Tensor | None = None,
    ) -> Tensor:
        """Autoregressive rollout: (B, A, steps, 2) positions, read from the output head as `self.output`
        says (`output_base`: last_step (B, A, 2), the last observed displacement, is needed for "cv_residual"
        and the goal outputs, goal (B, A, 2) for "goal_residual" and "relaxation_residual").

        At step s the decoder reads every earlier step of every agent (and the same step of others) plus
        the whole context; its own outputs are fed back detached, through `features`, which also lets
        ForceFormer recompute the forces from the predicted positions. Each layer caches the inputs of
        earlier steps' projected keys and values (and the context's, projected once), so a step costs one
        new row of attention instead of re-running the prefix (identical outputs in eval mode; in
        training only the dropout draws differ from the official code).

        repeat: z, last_pos and agent_mask hold `repeat` samples per window (repeat_interleave order)
        while context holds each window once: its keys are projected once and every sample's query
        attends to them without copies.
        """
        B, A, _ = last_pos.shape
        Tp = context.shape[1] // A
        cross = _token_masks(agent_mask[::repeat], repeat, Tp, causal=False)  # (B / repeat, repeat · A, Tp · A)
        memory = [layer.cross_attn.keys(context, A) for layer in self.decoder]  # once per rollout and window
        caches = [KeyCache(steps) for _ in self.decoder]
        # Step s may read every real agent's tokens of steps <= s; a padded query also sees itself.
        padded = cross is not None  # without padding no pair is masked: skip the masks
        own_token = torch.eye(A, dtype=torch.bool, device=agent_mask.device)[None, :, None, :]  # (1, A, 1, A)
        allowed_all = (agent_mask[:, None, None, :] | own_token).expand(B, A, steps, A).reshape(B, A, steps * A)
        positions = last_pos[:, :, None]  # (B, A, 1, 2)
        outputs = []
        for step in range(steps):
            tokens = torch.cat([features(positions, step), z], -1)[:, :, None]  # (B, A, 1, F + Z)
            x = self.decoder_embed(tokens, first_step=step)  # (B, A, D)
            allowed = allowed_all[:, :, : (step + 1) * A] if padded else None
            for layer, cache, keys in zip(self.decoder, caches, memory):
                queries, new_keys = layer.self_attn.project(x, A)
                self_keys = (queries, cache.append(new_keys))
                x = layer(x, keys, A, (allowed, cross), self_keys=self_keys, fold=repeat)
            delta = self.out(x).float()  # (B, A, 2)
            base = output_base(self.output, step, steps, last_pos, last_step, goal, self.relaxation_steps)
            if base is not None:
                delta = delta + base
            outputs.append(last_pos + delta)
            positions = torch.cat([positions, outputs[-1].detach()[:, :, None]], 2)
        return torch.stack(outputs, 2)


class LossParts(NamedTuple):
    total: Tensor
    recon: Tensor
    kl: Tensor  # after the free-bits clamp: what the loss sees (it never reads below kl_min)
    best_of_k: Tensor
    kl_unclamped: Tensor  # before it: what the posterior actually carries (logged, not optimised)


def _per_window(values: Tensor, agent_mask: Tensor) -> Tensor:
    """(B, A) per-agent values -> (B,) mean over each window's real agents."""
    return (values * agent_mask).sum(1) / agent_mask.sum(1).clamp_min(1)


def best_of_k(samples: Tensor, future: Tensor, agent_mask: Tensor) -> Tensor:
    """Per window (B,): mean over real agents of min over K of the squared error summed over steps and xy.

    samples (B, K, A, T, 2), future (B, A, T, 2), agent_mask (B, A).
    """
    error = ((samples - future[:, None]) ** 2).sum((-1, -2))  # (B, K, A)
    return _per_window(error.min(1).values, agent_mask)  # min per agent, independently


def cvae_loss(
    recon: Tensor, future: Tensor, q: Gaussian, p: Gaussian, samples: Tensor | None, agent_mask: Tensor, kl_min: float
) -> LossParts:
    """AgentFormer's loss, all weights 1: squared error summed over time and xy, mean over agents; the
    window's mean KL clamped below at kl_min (free bits); best-of-K over prior samples.

    Each term is computed per window exactly as the official one-window step does, then averaged over
    the batch's windows: a batched step is the mean of the per-window steps.
    """
    recon_term = _per_window(((recon - future) ** 2).sum((-1, -2)), agent_mask)
    kl_raw = _per_window(kl_divergence(q, p), agent_mask)
    kl_term = kl_raw.clamp_min(kl_min)
    sample_term = best_of_k(samples, future, agent_mask) if samples is not None else torch.zeros_like(kl_term)
    real = agent_mask.any(1)
    mean = lambda x: (x * real).sum() / real.sum().clamp_min(1)  # noqa: E731
    total = mean(recon_term + kl_term + sample_term)
    return LossParts(total, mean(recon_term), mean(kl_term), mean(sample_term), mean(kl_raw.detach()))
