"""Window slicing: counts follow the track-length formula, positions and neighbours are right."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fftool.dataset.windowing import slice_sequence

L, OBS = 20, 8


def _tracks(spans: list[tuple[int, int]]) -> tuple[np.ndarray, ...]:
    """Rows for pedestrians 1..n present on [start, end] (inclusive) each; x = step, y = ped."""
    steps, peds = [], []
    for ped, (start, end) in enumerate(spans, start=1):
        steps.extend(range(start, end + 1))
        peds.extend([ped] * (end - start + 1))
    step = np.array(steps, dtype=np.int64)
    ped_id = np.array(peds, dtype=np.int64)
    xy = np.stack([step.astype(float), ped_id.astype(float)], axis=1)
    return step, ped_id, step * 10, xy


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 60), st.integers(0, 45)), min_size=1, max_size=12))
def test_counts_follow_the_track_length_formula(raw_spans: list[tuple[int, int]]) -> None:
    spans = [(start, start + length) for start, length in raw_spans]
    result = slice_sequence(*_tracks(spans), window_len=L, obs_len=OBS)
    lengths = np.array([end - start + 1 for start, end in spans])
    assert result.agent_ped.size == np.maximum(lengths - L + 1, 0).sum()
    starts = {s for start, end in spans for s in range(start, end - L + 2)}
    assert result.first_step.tolist() == sorted(starts)
    assert result.n_agents.sum() == result.agent_ped.size
    lo = min(s for s, _ in spans)
    hi = max(e for _, e in spans)
    assert result.candidates == max(0, hi - lo + 1 - L + 1)


def test_positions_are_the_twenty_raw_rows_in_order() -> None:
    step, ped, frame, xy = _tracks([(0, 24), (3, 30)])
    shuffle = np.random.default_rng(0).permutation(step.size)  # input order must not matter
    result = slice_sequence(step[shuffle], ped[shuffle], frame[shuffle], xy[shuffle], L, OBS)
    for first, window, ped_id, positions in zip(
        result.first_step[result.agent_window], result.agent_window, result.agent_ped, result.agent_xy
    ):
        assert positions[:, 0].tolist() == list(range(first, first + L))
        assert (positions[:, 1] == ped_id).all()
        assert result.t0_step[window] == first + OBS - 1
        assert result.t0_frame_id[window] == (first + OBS - 1) * 10


def test_a_gap_breaks_the_window() -> None:
    # ped 1 is present on 0..19 and 21..45 (gap at 20): windows start at 0 and at 21..26 only.
    step, ped, frame, xy = _tracks([(0, 45)])
    keep = step != 20
    result = slice_sequence(step[keep], ped[keep], frame[keep], xy[keep], L, OBS)
    assert result.first_step.tolist() == [0, *range(21, 27)]


def test_neighbours_include_pedestrians_that_are_not_valid() -> None:
    # ped 1 is valid for window 0; ped 2 is present only at steps 5..9, ped 3 only after the window.
    step, ped, frame, xy = _tracks([(0, 19), (5, 9), (20, 25)])
    result = slice_sequence(step, ped, frame, xy, L, OBS)
    assert result.first_step.tolist() == [0]
    assert result.n_agents.tolist() == [1]
    assert result.n_present.tolist() == [2]


def test_window_stride_keeps_every_kth_start() -> None:
    step, ped, frame, xy = _tracks([(0, 40)])
    result = slice_sequence(step, ped, frame, xy, L, OBS, window_stride=5)
    assert result.first_step.tolist() == [0, 5, 10, 15, 20]
    assert result.candidates == 5


def test_no_valid_agent_gives_no_window() -> None:
    result = slice_sequence(*_tracks([(0, 10), (12, 25)]), window_len=L, obs_len=OBS)
    assert result.first_step.size == 0 and result.agent_xy.shape == (0, L, 2)
