"""The CVAE backbone: masking, agent-aware attention, KL free bits, best-of-K, shapes and gradients."""

from __future__ import annotations

import math

import pytest
import torch

from fftool.models.forceformer import (
    AgentAwareAttention,
    Dropout,
    ForceFormer,
    Gaussian,
    _token_masks,
    best_of_k,
    cvae_loss,
)

SMALL = {"d_model": 32, "n_heads": 4, "d_ff": 64, "dropout": 0.0, "n_layers": 2, "z_dim": 8}


def _newest_position(positions: torch.Tensor, step: int) -> torch.Tensor:
    """The decoder's step features here: the newest position, as AgentFormer feeds."""
    return positions[:, :, -1]


def _model(seed: int = 0) -> ForceFormer:
    torch.manual_seed(seed)
    return ForceFormer(input_dim=4, decoder_dim=2, **SMALL).eval()


def _run(model: ForceFormer, past: torch.Tensor, future: torch.Tensor, mask: torch.Tensor, z: torch.Tensor):
    context, agent_context = model.encode_past(past, mask)
    q = model.posterior(future, context, mask)
    p = model.prior(agent_context)
    out = model.decode(z, past[:, :, -1, :2], context, mask, 12, _newest_position)
    return q, p, out


def test_padded_agents_change_nothing() -> None:
    g = torch.Generator().manual_seed(1)
    past, future = torch.randn(2, 3, 8, 4, generator=g), torch.randn(2, 3, 12, 4, generator=g)
    z = torch.randn(2, 3, 8, generator=g)
    mask = torch.ones(2, 3, dtype=torch.bool)
    model = _model()
    q, p, out = _run(model, past, future, mask, z)
    pad = lambda x: torch.cat([x, 100 * torch.randn(x.shape[0], 2, *x.shape[2:], generator=g)], 1)  # noqa: E731
    padded_mask = torch.cat([mask, torch.zeros(2, 2, dtype=torch.bool)], 1)
    q2, p2, out2 = _run(model, pad(past), pad(future), padded_mask, pad(z))
    torch.testing.assert_close(out2[:, :3], out, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(q2.mu[:, :3], q.mu, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(p2.logvar[:, :3], p.logvar, atol=1e-5, rtol=1e-5)
    assert torch.isfinite(out2).all()


def _reference_attention(attn: AgentAwareAttention, query, key, agents: int, allowed):
    """Agent-aware attention the plain way: both full score matrices, chosen by a same-agent mask."""
    same = (torch.arange(query.shape[1])[:, None] % agents) == (torch.arange(key.shape[1])[None, :] % agents)
    heads = attn._heads
    other = heads(attn.q(query)) @ heads(attn.k(key)).transpose(-1, -2)
    own = heads(attn.q_self(query)) @ heads(attn.k_self(key)).transpose(-1, -2)
    scores = torch.where(same, own, other) / attn.d_head**0.5
    weights = torch.softmax(scores.masked_fill(~allowed[:, None], float("-inf")), -1)
    return attn.out((weights @ heads(attn.v(key))).transpose(1, 2).flatten(2))


@pytest.mark.parametrize(("t_query", "t_key", "causal"), [(2, 2, False), (3, 5, False), (1, 4, False), (4, 4, True)])
def test_agent_aware_attention_matches_the_two_matrix_definition(t_query: int, t_key: int, causal: bool) -> None:
    torch.manual_seed(0)
    attn = AgentAwareAttention(16, 2, 0.0).eval()
    agent_mask = torch.tensor([[True, True, True], [True, False, True]])
    query, key = torch.randn(2, t_query * 3, 16), torch.randn(2, t_key * 3, 16)
    allowed = _token_masks(agent_mask, t_query, t_key, causal)
    if t_query != t_key:
        allowed = allowed | torch.eye(t_query * 3, t_key * 3, dtype=torch.bool)  # no empty softmax row
    torch.testing.assert_close(attn(query, key, 3, allowed), _reference_attention(attn, query, key, 3, allowed))


@pytest.mark.parametrize(("t_query", "t_key", "causal"), [(3, 3, False), (2, 5, False), (4, 4, True)])
def test_agent_aware_attention_gradients_match_the_definition(t_query: int, t_key: int, causal: bool) -> None:
    """Gradients through the diagonal-only same-agent scores and in-place masking equal the plain definition."""
    torch.manual_seed(0)
    attn = AgentAwareAttention(16, 2, 0.0).double()
    agent_mask = torch.tensor([[True, True, True], [True, False, True]])
    query, key = torch.randn(2, t_query * 3, 16, dtype=torch.double), torch.randn(2, t_key * 3, 16, dtype=torch.double)
    allowed = _token_masks(agent_mask, t_query, t_key, causal)
    if t_query != t_key:
        allowed = allowed | torch.eye(t_query * 3, t_key * 3, dtype=torch.bool)
    upstream = torch.randn(2, t_query * 3, 16, dtype=torch.double)
    grads = []
    for forward in (attn, lambda *a: _reference_attention(attn, *a)):
        attn.zero_grad()
        q, k = query.clone().requires_grad_(), key.clone().requires_grad_()
        (forward(q, k, 3, allowed) * upstream).sum().backward()
        grads.append([q.grad, k.grad] + [param.grad.clone() for param in attn.parameters()])
    for ours, reference in zip(*grads):
        torch.testing.assert_close(ours, reference)


def test_stacked_projections_follow_the_weights_without_autograd() -> None:
    """Sampling keeps the stacked projection weights between steps: a changed weight (an optimiser step, a
    loaded checkpoint, a move to another device) must be read at the next call, with and without autograd."""
    torch.manual_seed(0)
    attn = AgentAwareAttention(16, 2, 0.0).eval()
    query, key = torch.randn(2, 6, 16), torch.randn(2, 9, 16)
    every_pair = torch.ones(2, 6, 9, dtype=torch.bool)
    with torch.no_grad():
        before = attn(query, key, 3, None)
        attn.q.weight.mul_(2.0)
        attn.k_self.bias.add_(0.5)
        after = attn(query, key, 3, None)
        torch.testing.assert_close(after, _reference_attention(attn, query, key, 3, every_pair))
        assert not torch.allclose(before, after)
        attn.load_state_dict(AgentAwareAttention(16, 2, 0.0).state_dict())
        torch.testing.assert_close(attn(query, key, 3, None), _reference_attention(attn, query, key, 3, every_pair))
    torch.testing.assert_close(attn(query, key, 3, None), _reference_attention(attn, query, key, 3, every_pair))


def test_cpu_dropout_drops_p_keeps_the_mean_and_repeats_with_the_seed() -> None:
    dropout = Dropout(0.1).train()
    x = torch.ones(400_000, requires_grad=True)
    torch.manual_seed(3)
    y = dropout(x)
    assert abs(float((y == 0).float().mean()) - 0.1) < 0.003
    assert abs(float(y.detach().mean()) - 1) < 0.005  # kept values scaled by 1 / (1 - p)
    y.sum().backward()
    torch.testing.assert_close(x.grad, y.detach())  # the gradient is the same mask
    torch.manual_seed(3)
    assert torch.equal(dropout(x), y)
    assert not torch.equal(dropout(x), y)  # the next draw differs
    assert dropout.eval()(x) is x


def test_agent_aware_attention_separates_self_from_others() -> None:
    torch.manual_seed(0)
    attn = AgentAwareAttention(16, 2, 0.0).eval()
    x = torch.randn(1, 6, 16)
    allowed = torch.ones(1, 6, 6, dtype=torch.bool)
    reference = torch.nn.MultiheadAttention(16, 2, batch_first=True)
    reference.in_proj_weight.data = torch.cat([attn.q.weight, attn.k.weight, attn.v.weight])
    reference.in_proj_bias.data = torch.cat([attn.q.bias, attn.k.bias, attn.v.bias])
    reference.out_proj.load_state_dict(attn.out.state_dict())
    plain = reference(x, x, x, need_weights=False)[0]
    assert not torch.allclose(attn(x, x, 3, allowed), plain, atol=1e-4)  # own projections differ: not plain
    # with the self projections equal to the others', it is plain multi-head attention
    attn.q_self.load_state_dict(attn.q.state_dict())
    attn.k_self.load_state_dict(attn.k.state_dict())
    torch.testing.assert_close(attn(x, x, 3, allowed), plain, atol=1e-6, rtol=1e-5)


def test_token_masks_are_time_major_and_causal() -> None:
    mask = torch.tensor([[True, True, False]])
    allowed = _token_masks(mask, 2, 2, causal=True)
    assert allowed[0, 4, 0] and allowed[0, 4, 3] and not allowed[0, 0, 4]  # step 1 sees step 0, not vice versa
    assert not allowed[0, 0, 2] and allowed[0, 2, 2]  # padded keys hidden; a padded query sees itself


def test_kl_is_clamped_below_at_free_bits() -> None:
    mu = torch.zeros(1, 2, 4, requires_grad=True)
    q = Gaussian(mu, torch.zeros(1, 2, 4))
    p = Gaussian(torch.zeros(1, 2, 4), torch.zeros(1, 2, 4))
    future = torch.zeros(1, 2, 12, 2)
    mask = torch.ones(1, 2, dtype=torch.bool)
    parts = cvae_loss(future, future, q, p, future[:, None], mask, kl_min=2.0)
    assert parts.kl.item() == 2.0
    parts.total.backward()
    assert mu.grad is not None and torch.count_nonzero(mu.grad) == 0  # no gradient below the clamp
    far = Gaussian(torch.full((1, 2, 4), 3.0), torch.zeros(1, 2, 4))
    assert cvae_loss(future, future, far, p, future[:, None], mask, 2.0).kl.item() == pytest.approx(18.0)


def test_best_of_k_picks_each_agents_best_sample() -> None:
    future = torch.zeros(1, 2, 12, 2)
    samples = torch.stack([torch.full((2, 12, 2), 1.0), torch.full((2, 12, 2), 3.0)])[None]  # (1, K=2, A, T, 2)
    samples[0, 1, 1] = 0.5  # agent 1's best is sample 1, agent 0's is sample 0
    mask = torch.ones(1, 2, dtype=torch.bool)
    expected = (1.0**2 * 24 + 0.5**2 * 24) / 2
    assert best_of_k(samples, future, mask).item() == pytest.approx(expected)
    assert best_of_k(samples, future, torch.tensor([[True, False]])).item() == pytest.approx(24.0)


def test_training_step_runs_forward_and_backward() -> None:
    model = _model().train()
    g = torch.Generator().manual_seed(3)
    past, future = torch.randn(2, 4, 8, 4, generator=g), torch.randn(2, 4, 12, 4, generator=g)
    mask = torch.tensor([[True, True, True, False], [True, False, False, False]])
    context, agent_context = model.encode_past(past, mask)
    q, p = model.posterior(future, context, mask), model.prior(agent_context)
    recon = model.decode(q.sample(g), past[:, :, -1, :2], context, mask, 12, _newest_position)
    k = 3
    rep = lambda x: x.repeat_interleave(k, 0)  # noqa: E731
    z = Gaussian(rep(p.mu), rep(p.logvar)).sample(g)
    samples = model.decode(z, rep(past[:, :, -1, :2]), context, rep(mask), 12, _newest_position, repeat=k)
    parts = cvae_loss(recon, future[..., :2], q, p, samples.view(2, k, 4, 12, 2), mask, 2.0)
    parts.total.backward()
    assert recon.shape == (2, 4, 12, 2) and torch.isfinite(parts.total)
    missing = [name for name, param in model.named_parameters() if param.grad is None]
    assert missing == []


def _decode_by_recomputation(model: ForceFormer, z, last_pos, context, mask, steps):
    """The official way: re-run the whole decoder over every step so far, at every step."""
    B, A, _ = last_pos.shape
    Tp = context.shape[1] // A
    positions, inputs, outputs = last_pos[:, :, None], [], []
    for step in range(steps):
        inputs.append(torch.cat([_newest_position(positions, step), z], -1))
        x = model.decoder_embed(torch.stack(inputs, 2))
        masks = (_token_masks(mask, step + 1, step + 1, causal=True), _token_masks(mask, step + 1, Tp, causal=False))
        for layer in model.decoder:
            x = layer(x, context, A, masks)
        outputs.append(last_pos + model.out(x[:, -A:]))
        positions = torch.cat([positions, outputs[-1][:, :, None]], 2)
    return torch.stack(outputs, 2)


def test_cached_decoding_equals_recomputing_the_prefix() -> None:
    model = _model(5)
    g = torch.Generator().manual_seed(2)
    past = torch.randn(2, 3, 8, 4, generator=g)
    mask = torch.tensor([[True, True, True], [True, True, False]])
    context, _ = model.encode_past(past, mask)
    z = torch.randn(2, 3, 8, generator=g)
    with torch.no_grad():
        fast = model.decode(z, past[:, :, -1, :2], context, mask, 12, _newest_position)
        slow = _decode_by_recomputation(model, z, past[:, :, -1, :2], context, mask, 12)
    torch.testing.assert_close(fast[mask], slow[mask], atol=1e-5, rtol=1e-5)


def test_sharing_the_context_between_samples_equals_repeating_it() -> None:
    model = _model(6)
    g = torch.Generator().manual_seed(3)
    past = torch.randn(2, 3, 8, 4, generator=g)
    mask = torch.tensor([[True, True, True], [True, False, False]])
    context, _ = model.encode_past(past, mask)
    k = 4
    rep = lambda x: x.repeat_interleave(k, 0)  # noqa: E731
    z = torch.randn(2 * k, 3, 8, generator=g)
    with torch.no_grad():
        shared = model.decode(z, rep(past[:, :, -1, :2]), context, rep(mask), 12, _newest_position, repeat=k)
        copied = model.decode(z, rep(past[:, :, -1, :2]), rep(context), rep(mask), 12, _newest_position)
    torch.testing.assert_close(shared[rep(mask)], copied[rep(mask)], atol=1e-5, rtol=1e-5)


def test_output_types_read_the_head_as_documented() -> None:
    """A constant head shows what each output type adds it to: the last position, constant velocity, or the
    constant-acceleration curve that leaves with the last step and reaches the goal at step 12."""
    g = torch.Generator().manual_seed(3)
    past, mask = torch.randn(1, 2, 8, 4, generator=g), torch.ones(1, 2, dtype=torch.bool)
    z, last, step = torch.randn(1, 2, 8, generator=g), past[:, :, -1, :2], torch.tensor([[[0.1, 0.2], [-0.3, 0.0]]])
    goal = last + torch.tensor([[[3.0, 2.4], [-3.6, 1.44]]])  # agent 0: 1.8 m past constant velocity's end, 0 across
    steps = torch.arange(1, 13, dtype=torch.float32)[None, None, :, None]
    acceleration = torch.tensor([[[1.8 / 144, 0.0], [0.0, 0.01]]])  # (goal - last - 12 step) / 12², by hand
    expected = {
        "offset": last[:, :, None] + 0.5,
        "cv_residual": last[:, :, None] + steps * step[:, :, None] + 0.5,
        "goal_residual": last[:, :, None] + steps * step[:, :, None] + steps**2 * acceleration[:, :, None] + 0.5,
    }
    for output, positions in expected.items():
        torch.manual_seed(0)
        model = ForceFormer(input_dim=4, decoder_dim=2, output=output, **SMALL).eval()
        torch.nn.init.zeros_(model.out.weight)
        torch.nn.init.constant_(model.out.bias, 0.5)
        context, _ = model.encode_past(past, mask)
        out = model.decode(z, last, context, mask, 12, _newest_position, last_step=step, goal=goal)
        torch.testing.assert_close(out, positions.expand_as(out), msg=output)
    torch.testing.assert_close(out[:, :, -1], goal + 0.5)  # goal_residual's curve ends at the goal


def test_the_relaxation_path_is_the_driving_force_toward_a_constant_step() -> None:
    """relaxation_residual's path, checked by its definition rather than its formula: it leaves with the last
    observed step, every change of step is λ = exp(-1 / τ) times the one before (a driving force relaxing toward
    one constant step, Helbing's F = (w − v) / τ per step), and it reaches the goal at step 12; τ → 0 is the
    straight line to the goal at constant speed."""
    g = torch.Generator().manual_seed(4)
    past, mask = torch.randn(1, 2, 8, 4, generator=g), torch.ones(1, 2, dtype=torch.bool)
    z, last, step = torch.randn(1, 2, 8, generator=g), past[:, :, -1, :2], torch.tensor([[[0.1, 0.2], [-0.3, 0.0]]])
    goal = last + torch.tensor([[[3.0, 2.4], [-3.6, 1.44]]])
    for tau in (1.0, 5.0, 1e-3):
        torch.manual_seed(0)
        model = ForceFormer(input_dim=4, decoder_dim=2, output="relaxation_residual", relaxation_steps=tau, **SMALL)
        torch.nn.init.zeros_(model.out.weight)
        torch.nn.init.zeros_(model.out.bias)
        context, _ = model.eval().encode_past(past, mask)
        out = model.decode(z, last, context, mask, 12, _newest_position, last_step=step, goal=goal).double()
        steps = torch.diff(torch.cat([(last - step).double()[:, :, None], last.double()[:, :, None], out], 2), dim=2)
        changes = torch.diff(steps, dim=2)  # (B, A, 12, 2): step n+1 − step n, from the last observed one on
        torch.testing.assert_close(changes[:, :, 1:], math.exp(-1 / tau) * changes[:, :, :-1], atol=1e-6, rtol=0)
        torch.testing.assert_close(out[:, :, -1], goal.double(), atol=1e-5, rtol=0)
    straight = last[:, :, None] + torch.arange(1, 13)[None, None, :, None] * (goal - last)[:, :, None] / 12
    torch.testing.assert_close(out.float(), straight, atol=1e-5, rtol=0)


def test_the_output_head_init_is_a_parameter() -> None:
    wide = ForceFormer(input_dim=4, decoder_dim=2, out_init_std=1.0, **SMALL)
    assert 0.5 < float(wide.out.weight.detach().std()) < 1.5 and float(_model().out.weight.detach().std()) < 0.02
