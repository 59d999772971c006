"""Force math: hand-computed cases, symmetry, decay, masking, and the independent socialforce package."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from fftool.config import ForcesConfig
from fftool.science.social_forces import (
    desired_direction,
    driving_force,
    ellipse_b,
    finite_difference_velocity,
    fov_weight,
    group_ids,
    pair_repulsion,
    potential,
    same_group,
    social_forces,
)

CFG = ForcesConfig()


@pytest.fixture(autouse=True)
def float64_by_default():
    """These checks compare to 1e-6 and 1e-12: float64, restored afterwards so no other test is affected."""
    previous = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    yield
    torch.set_default_dtype(previous)


def _hand_pair_force(ra, rb, vb, gb, v0=2.1, sigma=0.3, dt=0.4):
    """Force on a from b, in plain floats, straight from the equations (no torch, no vectors library)."""
    rx, ry = ra[0] - rb[0], ra[1] - rb[1]
    ex, ey = gb[0] - rb[0], gb[1] - rb[1]
    en = math.hypot(ex, ey)
    ex, ey = ex / en, ey / en
    step = math.hypot(*vb) * dt
    ax, ay = rx - step * ex, ry - step * ey
    n1, n2 = math.hypot(rx, ry), math.hypot(ax, ay)
    b = 0.5 * math.sqrt((n1 + n2) ** 2 - step**2)
    value = v0 * math.exp(-b / sigma)
    scale = value / sigma * (n1 + n2) / (4 * b)
    return b, value, (scale * (rx / n1 + ax / n2), scale * (ry / n1 + ay / n2))


def _scene(positions, velocities, goals, steps=1):
    """A one-window batch where every agent keeps its state at each step."""
    pos = torch.tensor(positions)[None, :, None, :].expand(1, -1, steps, 2).clone()
    vel = torch.tensor(velocities)[None, :, None, :].expand(1, -1, steps, 2).clone()
    goal = torch.tensor(goals)[None]
    present = torch.ones(pos.shape[:3], dtype=torch.bool)
    speed0 = torch.linalg.vector_norm(vel, dim=-1)
    return pos, present, goal, vel, speed0


def _total(positions, velocities, goals, cfg=CFG, groups=None):
    pos, present, goal, vel, speed0 = _scene(positions, velocities, goals)
    n = len(positions)
    groups = torch.zeros(1, n, n, dtype=torch.bool) if groups is None else groups
    f_dr, f_re = social_forces(pos, present, goal, vel, speed0, groups, cfg)
    return f_dr[0, :, 0], f_re[0, :, 0]


def test_head_on_matches_the_hand_computation() -> None:
    positions, velocities, goals = [(0.0, 0.0), (2.0, 0.0)], [(1.0, 0.0), (-1.0, 0.0)], [(10.0, 0.0), (-10.0, 0.0)]
    _, f_re = _total(positions, velocities, goals)
    b, value, expected = _hand_pair_force(positions[0], positions[1], velocities[1], goals[1])
    assert b == pytest.approx(1.7888543819998317)  # sqrt(3.6^2 - 0.4^2) / 2
    assert value == pytest.approx(2.1 * math.exp(-b / 0.3))
    np.testing.assert_allclose(f_re[0].numpy(), expected, rtol=1e-12)
    assert f_re[0, 0] < 0 and abs(f_re[0, 1]) < 1e-15  # pushed straight back, away from beta
    np.testing.assert_allclose(f_re[1].numpy(), -f_re[0].numpy(), rtol=1e-12)  # mirror image


def test_side_by_side_pushes_apart_and_slightly_back() -> None:
    positions, velocities, goals = [(0.0, 0.0), (0.0, 1.0)], [(1.0, 0.0), (1.0, 0.0)], [(10.0, 0.0), (10.0, 1.0)]
    _, f_re = _total(positions, velocities, goals)
    _, _, expected = _hand_pair_force(positions[0], positions[1], velocities[1], goals[1])
    np.testing.assert_allclose(f_re[0].numpy(), expected, rtol=1e-12)  # 90° is inside the 200° cone: w = 1
    assert f_re[0, 1] < 0 and f_re[0, 0] < 0 and f_re[1, 1] > 0


def test_behind_is_out_of_view_and_halved() -> None:
    positions, velocities, goals = [(0.0, 0.0), (-1.0, 0.0)], [(1.0, 0.0), (1.0, 0.0)], [(10.0, 0.0), (10.0, 0.0)]
    _, f_re = _total(positions, velocities, goals)
    _, _, on_front = _hand_pair_force(positions[0], positions[1], velocities[1], goals[1])
    _, _, on_back = _hand_pair_force(positions[1], positions[0], velocities[0], goals[0])
    np.testing.assert_allclose(f_re[0].numpy(), 0.5 * np.array(on_front), rtol=1e-12)  # beta behind alpha: c
    np.testing.assert_allclose(f_re[1].numpy(), on_back, rtol=1e-12)  # alpha ahead of beta: 1


def test_a_group_does_not_repel() -> None:
    positions, velocities, goals = [(0.0, 0.0), (0.0, 0.6)], [(1.0, 0.0), (1.0, 0.0)], [(10.0, 0.0), (10.0, 0.6)]
    groups = torch.tensor([[[False, True], [True, False]]])
    _, f_re = _total(positions, velocities, goals, groups=groups)
    assert torch.count_nonzero(f_re) == 0
    _, apart = _total(positions, velocities, goals)
    assert torch.count_nonzero(apart) == 4


def test_driving_force_closed_forms() -> None:
    e = torch.tensor([[1.0, 0.0]])
    defined = torch.tensor([True])
    at_rest = driving_force(torch.zeros(1, 2), e, defined, torch.tensor([1.2]), 0.5)
    np.testing.assert_allclose(at_rest.numpy(), [[2.4, 0.0]])  # v0 e / tau
    cruising = driving_force(torch.tensor([[1.2, 0.0]]), e, defined, torch.tensor([1.2]), 0.5)
    assert torch.count_nonzero(cruising) == 0


def test_forces_are_zero_at_the_goal() -> None:
    direction, defined = desired_direction(torch.tensor([[3.0, 4.0]]), torch.tensor([[3.0, 4.0]]), 1e-3)
    assert not defined.any() and torch.count_nonzero(direction) == 0
    f_dr, f_re = _total([(3.0, 4.0), (3.5, 4.0)], [(1.0, 0.0), (-1.0, 0.0)], [(3.0, 4.0), (0.0, 4.0)])
    assert torch.count_nonzero(f_dr[0]) == 0 and torch.count_nonzero(f_re[0]) == 0
    assert f_re[1, 0] > 0  # beta still feels alpha (pushed away along +x)


@settings(max_examples=50, deadline=None)
@given(
    st.floats(-5, 5),
    st.floats(-5, 5),
    st.floats(0.2, 8.0),
    st.floats(0, 2 * math.pi),
)
def test_static_pairs_are_antisymmetric_and_decay(x: float, y: float, distance: float, angle: float) -> None:
    # Standing pedestrians: b = |r|, so f_ab = -f_ba and |f| falls with distance.
    ra = torch.tensor([x, y])
    rb = ra + distance * torch.tensor([math.cos(angle), math.sin(angle)])
    pos = torch.stack([ra, rb])
    r_ab = pos[:, None] - pos[None, :]
    kwargs = {"v0_m2_s2": 2.1, "sigma_m": 0.3, "step_s": 0.4}
    f = pair_repulsion(r_ab, torch.zeros(2), torch.zeros(2, 2), **kwargs)
    torch.testing.assert_close(f[0, 1], -f[1, 0])
    np.testing.assert_allclose(ellipse_b(r_ab, torch.zeros(2), torch.zeros(2, 2), 0.4).b[0, 1], distance, rtol=1e-9)
    farther = torch.stack([ra, ra + 1.1 * (rb - ra)])
    f_far = pair_repulsion(farther[:, None] - farther[None, :], torch.zeros(2), torch.zeros(2, 2), **kwargs)
    assert torch.linalg.vector_norm(f_far[0, 1]) < torch.linalg.vector_norm(f[0, 1])


def test_padded_agents_change_nothing() -> None:
    positions, velocities = [(0.0, 0.0), (1.5, 0.4)], [(1.0, 0.0), (-0.8, 0.1)]
    goals = [(10.0, 0.0), (-8.0, 1.0)]
    f_dr, f_re = _total(positions, velocities, goals)
    pos, present, goal, vel, speed0 = _scene([*positions, (0.5, 0.1)], [*velocities, (0.0, 0.0)], [*goals, (0.5, 0.1)])
    present[:, 2] = False  # a padded slot sitting right next to alpha
    padded = social_forces(pos, present, goal, vel, speed0, torch.zeros(1, 3, 3, dtype=torch.bool), CFG)
    torch.testing.assert_close(padded[0][0, :2, 0], f_dr, rtol=0, atol=0)
    torch.testing.assert_close(padded[1][0, :2, 0], f_re, rtol=0, atol=0)
    assert torch.count_nonzero(padded[1][0, 2]) == 0


def test_forces_are_differentiable() -> None:
    pos, present, goal, vel, speed0 = _scene([(0.0, 0.0), (1.0, 0.5)], [(1.0, 0.0), (-1.0, 0.0)], [(9, 0), (-9, 0)])
    pos.requires_grad_(True)
    _, f_re = social_forces(pos, present, goal, vel, speed0, torch.zeros(1, 2, 2, dtype=torch.bool), CFG)
    f_re.sum().backward()
    assert torch.isfinite(pos.grad).all() and torch.count_nonzero(pos.grad) > 0


def test_velocity_is_causal_and_backward() -> None:
    pos = torch.arange(20, dtype=torch.float64)[None, None, :, None].expand(1, 1, 20, 2) ** 2 * 0.1
    present = torch.ones(1, 1, 20, dtype=torch.bool)
    vel = finite_difference_velocity(pos, present, 0.4, 8)
    torch.testing.assert_close(vel[0, 0, 5], (pos[0, 0, 5] - pos[0, 0, 4]) / 0.4)
    torch.testing.assert_close(vel[0, 0, 0], vel[0, 0, 1])  # AgentFormer's duplicated first velocity
    present[0, 0, :7] = False  # first seen at the last observed step: no velocity from the future
    vel = finite_difference_velocity(pos, present, 0.4, 8)
    assert torch.count_nonzero(vel[0, 0, 7]) == 0
    torch.testing.assert_close(vel[0, 0, 8], (pos[0, 0, 8] - pos[0, 0, 7]) / 0.4)


def test_group_mask_counts_more_than_sigma_steps() -> None:
    labels = torch.tensor([[[0, 0, 0, 0, 0, -1, -1, -1], [0, 0, 0, 0, 0, 1, 1, 1], [0, 0, 0, 0, -1, -1, -1, -1]]])
    groups = same_group(labels, 4)
    assert groups[0, 0, 1] and not groups[0, 0, 2] and not groups[0, 1, 2]  # 5 shared steps vs 4
    chain = torch.zeros(1, 4, 4, dtype=torch.bool)
    chain[0, 0, 1] = chain[0, 1, 0] = chain[0, 1, 2] = chain[0, 2, 1] = True
    assert group_ids(chain).tolist() == [[0, 0, 0, -1]]


def test_golden_vector_from_socialforce_guide() -> None:
    # research/ecosystem.md §c.2: three pedestrians (x, y, vx, vy, dx, dy), all in view of each other.
    state = torch.tensor([[0, 0, 1, 0, 10, 0], [2, 0.3, -1, 0, -10, 0.3], [1, -1.5, 0, 1.2, 1, 10]])
    _, f_re = _total(state[:, :2].tolist(), state[:, 2:4].tolist(), state[:, 4:6].tolist())
    expected = [(-0.038026, 0.023855), (0.024705, 0.015481), (0.007395, -0.030725)]
    np.testing.assert_allclose(f_re.numpy(), expected, atol=1e-6)


# --- the independent socialforce package (svenkreiss/socialforce 0.2.3) -------------------------------


def _random_states(seed: int, n: int = 9) -> torch.Tensor:
    rng = np.random.default_rng(seed)
    position = rng.uniform(-4, 4, (n, 2))
    velocity = rng.normal(0, 1.0, (n, 2))
    goal = position + rng.normal(0, 6, (n, 2))
    return torch.tensor(np.concatenate([position, velocity, goal], axis=1))


@pytest.mark.parametrize("seed", range(10))
def test_b_v_and_f_match_the_socialforce_package(seed: int) -> None:
    import socialforce
    from socialforce.potentials import PedPedPotential

    state = _random_states(seed)
    simulator = socialforce.Simulator(ped_ped=PedPedPotential(v0=2.1, sigma=0.3), delta_t=0.4, tau=0.5)
    full = simulator.normalize_state(state)
    r_ab = PedPedPotential.r_ab(full)
    speeds = socialforce.stateutils.speeds(full)
    e = socialforce.stateutils.desired_directions(full)
    their_b = simulator.V.b(r_ab, speeds, e)
    their_v = simulator.V.value_b(their_b)
    their_f = simulator.f_ab(full)

    ours_e, _ = desired_direction(state[:, :2], state[:, 4:6], CFG.goal_min_distance_m)
    ours_b = ellipse_b(r_ab, speeds, ours_e, 0.4).b
    ours_f = pair_repulsion(r_ab, speeds, ours_e, v0_m2_s2=2.1, sigma_m=0.3, step_s=0.4)
    off = ~torch.eye(len(state), dtype=torch.bool)
    torch.testing.assert_close(ours_b[off], their_b[off], rtol=0, atol=1e-6)
    torch.testing.assert_close(potential(ours_b, 2.1, 0.3)[off], their_v[off], rtol=0, atol=1e-6)
    torch.testing.assert_close(ours_f[off], their_f.detach()[off], rtol=0, atol=1e-6)

    fov = socialforce.FieldOfView(twophi=200.0)
    their_position_w = fov(e, -r_ab)
    their_force_w = fov(e, -their_f.detach())
    torch.testing.assert_close(fov_weight(ours_e, -r_ab, 200.0, 0.5)[off], their_position_w[off])
    torch.testing.assert_close(fov_weight(ours_e, -ours_f, 200.0, 0.5)[off], their_force_w[off])


def test_the_two_fov_readings_differ_somewhere() -> None:
    # Guards against a silently ignored `fov_reading` switch.
    differs = 0
    for seed in range(20):
        state = _random_states(seed, n=12)
        e, _ = desired_direction(state[:, :2], state[:, 4:6], 1e-3)
        r_ab = state[:, None, :2] - state[None, :, :2]
        f = pair_repulsion(
            r_ab, torch.linalg.vector_norm(state[:, 2:4], dim=-1), e, v0_m2_s2=2.1, sigma_m=0.3, step_s=0.4
        )
        differs += int((fov_weight(e, -f, 200.0, 0.5) != fov_weight(e, -r_ab, 200.0, 0.5)).sum())
    assert differs > 0
