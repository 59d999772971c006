"""Figures a newcomer reads without help: keys in the drawn colours, titles with the setting, distinct
windows, counts per density bin, and a key for every map channel."""

from __future__ import annotations

from itertools import combinations
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.colors import to_hex, to_rgb
from matplotlib.container import ErrorbarContainer

from fftool.config import MapsConfig
from fftool.learning.batches import AgentWindows
from fftool.reporting import plots
from fftool.stages.maps import _channel_key, _check_figure, _check_figure_drawn, build_scene
from tests.test_maps import make_scene

OBS, PRED, K = 8, 12, 3
WINDOW_LEN = OBS + PRED


def recordings(steps: dict[str, int], agents: int = 3, seed: int = 0) -> AgentWindows:
    """One window per start step (stride 1, like the benchmark) in each recording, `agents` agents each;
    window ids run on across recordings, as in a windows artifact."""
    rng = np.random.default_rng(seed)
    source, first, window, ped = [], [], [], []
    wid = 0
    for name, count in steps.items():
        for step in range(count):
            for agent in range(agents):
                source.append(name)
                first.append(step)
                window.append(wid)
                ped.append(agent)
            wid += 1
    n = len(window)
    xy = np.cumsum(rng.normal(0.0, 0.3, (n, WINDOW_LEN, 2)), axis=1) + rng.uniform(0, 10, (n, 1, 2))
    return AgentWindows(xy, np.array(source), np.array(first), np.array(window), np.array(ped), np.arange(n))


def evaluation(data: AgentWindows, predictor: str, ade: np.ndarray, protocol: str = "paper") -> plots.Evaluation:
    """Predictions for every agent of `data`; ade[window] is each agent's minADE in that window."""
    rng = np.random.default_rng(len(predictor))
    n_agents = pd.Series(data.window_id).map(pd.Series(data.window_id).value_counts()).to_numpy()
    last = data.xy[:, OBS - 1 : OBS]  # (M, 1, 2)
    pred = last[:, None] + rng.normal(0.0, 0.5, (len(data), K, PRED, 2))
    frame = pd.DataFrame(
        {
            "window_id": data.window_id,
            "ped_id": data.ped_id,
            "agent_row": data.row,
            "n_agents": n_agents.astype(np.int32),
            "min_ade": ade[data.window_id].astype(np.float32),
            "min_fde": (2 * ade[data.window_id]).astype(np.float32),
            "best_k": np.zeros(len(data), np.int16),
            "collisions": rng.integers(0, 3, len(data)).astype(np.int32),
            "pred": list(pred.reshape(len(data), -1)),
        }
    )
    return plots.Evaluation(predictor, K, frame, protocol=protocol, benchmark="zara1", part="test")


def close_pairs(picked: list[int], data: AgentWindows) -> list[tuple[int, int]]:
    when = {int(w): (str(s), int(f)) for w, s, f in zip(data.window_id, data.source, data.first_step, strict=True)}
    return [
        (a, b)
        for a, b in combinations(picked, 2)
        if when[a][0] == when[b][0] and abs(when[a][1] - when[b][1]) < WINDOW_LEN
    ]


def test_the_picked_windows_are_a_window_apart_and_disagree_most() -> None:
    data = recordings({"crowds_zara01": 70, "crowds_zara02": 30})
    spread = np.zeros(100)
    spread[[10, 11, 12, 13]] = [1.0, 0.99, 0.98, 0.97]  # a run of near-duplicate windows: one of them is drawn
    spread[[25, 31, 75]] = [0.9, 0.8, 0.7]  # 25 is 15 steps after 10 (same recording): too close; 75 another
    evaluations = [evaluation(data, "baseline", 0.5 + spread), evaluation(data, "dr", 0.5 - spread)]
    picked = plots.pick_windows(evaluations, 3, data, window_len=WINDOW_LEN)
    assert picked == [10, 31, 75]
    for seed in range(5):  # random scores: never two windows that share a time step of a recording
        noise = np.random.default_rng(seed).uniform(0, 1, 100)
        evaluations = [evaluation(data, "baseline", noise), evaluation(data, "dr", noise[::-1].copy())]
        for count in (1, 3, 6, 20):
            picked = plots.pick_windows(evaluations, count, data, window_len=WINDOW_LEN)
            assert 1 <= len(picked) <= count and len(set(picked)) == len(picked)
            assert not close_pairs(picked, data), picked
    # 70 + 30 start steps hold at most 4 + 2 windows that far apart: fewer come back, never a close pair
    assert len(plots.pick_windows(evaluations, 20, data, window_len=WINDOW_LEN)) <= 6
    # without the windows, ids stand in for time steps
    no_data = plots.pick_windows(evaluations, 6, window_len=WINDOW_LEN)
    assert all(abs(a - b) >= WINDOW_LEN for a, b in combinations(no_data, 2))


def test_windows_with_several_agents_come_first() -> None:
    lonely, busy = recordings({"biwi_eth": 40}, agents=1), recordings({"biwi_eth": 40}, agents=3)
    offset = busy.window_id.max() + 1
    data = AgentWindows(
        np.concatenate([lonely.xy, busy.xy]),
        np.array(["biwi_eth"] * len(lonely) + ["biwi_hotel"] * len(busy)),
        np.concatenate([lonely.first_step, busy.first_step]),
        np.concatenate([lonely.window_id + offset, busy.window_id]),
        np.concatenate([lonely.ped_id, busy.ped_id]),
        np.arange(len(lonely) + len(busy)),
    )
    spread = np.linspace(0, 1, 2 * offset)  # the lonely windows (ids offset..) differ most
    evaluations = [evaluation(data, "baseline", 1 + spread), evaluation(data, "re", 1 - spread)]
    picked = plots.pick_windows(evaluations, 3, data, window_len=WINDOW_LEN)
    assert all(w < offset for w in picked[:2])  # the 3-agent recording holds two windows a window apart
    assert picked[2] >= offset  # then the single-agent windows


def test_the_qualitative_key_and_title_match_the_predictors(tmp_path: Path) -> None:
    data = recordings({"uni_examples": 50})  # a recording without a scene image: drawn in metres
    spread = np.linspace(0, 1, 50)
    evaluations = [
        evaluation(data, "cv", 1 + spread, protocol="none"),
        evaluation(data, "baseline", 1 - spread, protocol="none"),
        evaluation(data, "dr", 1 + 0 * spread),
    ]
    windows = plots.pick_windows(evaluations, 2, data, window_len=WINDOW_LEN)
    how = plots.pick_rule(len(evaluations), WINDOW_LEN)
    fig = plots.qualitative_figure(evaluations, data, windows, tmp_path, OBS, False, how=how)
    (key,) = fig.legends
    labels = [t.get_text() for t in key.get_texts()]
    colours = [to_hex(h.get_color()) for h in key.legend_handles]
    assert labels[:2] == ["observed (past)", "ground truth (future)"] and colours[:2] == ["#000000"] * 2
    assert labels[2:] == [f"{e.name}: K = {K} samples" for e in evaluations]
    assert colours[2:] == [plots.COLOURS[e.predictor] for e in evaluations]
    axes = np.array(fig.axes).reshape(len(windows), len(evaluations))
    for col, e in enumerate(evaluations):  # every predicted path is drawn in its predictor's colour
        drawn = {to_hex(line.get_color()) for ax in axes[:, col] for line in ax.get_lines()}
        assert drawn - {"#000000", "#ffffff"} == {plots.COLOURS[e.predictor]}
        assert axes[0, col].get_title() == e.name
    for row in axes:  # one window's panels share one extent, so its predictors compare at one scale
        assert len({(ax.get_xlim(), ax.get_ylim()) for ax in row}) == 1
        (x0, x1), (y0, y1) = row[0].get_xlim(), row[0].get_ylim()
        points = np.concatenate([line.get_xydata() for ax in row for line in ax.get_lines()])
        assert (points[:, 0] > x0).all() and (points[:, 0] < x1).all() and (points[:, 1] > y0).all()
        assert (points[:, 1] < y1).all()
    title = fig._suptitle.get_text().replace("\n", " ")
    assert title.startswith("zara1 (test part)") and f"K = {K} samples" in title
    assert "goal protocol 'paper'" in title and "constant velocity, AgentFormer read no goal" in title
    assert any("Windows chosen automatically" in t.get_text() for t in fig.texts)
    plt.close(fig)
    best = plots.legend_handles(evaluations, best_only=True)
    assert best[-1].get_label() == f"ForceFormer-Dr: best of K = {K} samples"
    out = plots.qualitative(evaluations, data, windows, tmp_path, OBS, True, tmp_path / "q.png", how=how)
    assert out.read_bytes()[:4] == b"\x89PNG"


def test_setting_names_k_and_the_goal_protocols() -> None:
    data = recordings({"biwi_eth": 2})
    base = evaluation(data, "baseline", np.ones(2), protocol="none")
    assert plots.setting([base]) == f"K = {K} samples per agent; goal protocol 'none' (no predictor here reads a goal)"
    mixed = [base, evaluation(data, "dr", np.ones(2), "paper"), evaluation(data, "re", np.ones(2), "fair")]
    assert "goal protocols 'paper' (ForceFormer-Dr), 'fair' (ForceFormer-Re)" in plots.setting(mixed)
    unknown = plots.Evaluation("goal", 5, base.frame)  # built by hand: no protocol known, none claimed
    assert plots.setting([unknown]) == "K = 5 samples per agent"


def test_the_density_figure_counts_every_bin_and_keeps_its_key_off_the_curves() -> None:
    data = recordings({"crowds_zara01": 30}, agents=2)
    more = recordings({"crowds_zara02": 30}, agents=5)
    frames = {}
    for predictor in ("baseline", "dr"):
        a, b = evaluation(data, predictor, np.ones(30)), evaluation(more, predictor, np.ones(30))
        frames[predictor] = pd.concat([a.frame, b.frame.assign(window_id=b.frame["window_id"] + 30)])
    fig = plots.density_figure({"zara1": frames}, title="zara1 (test part): K = 3 samples per agent")
    curves = [ax for ax in fig.axes if ax.get_lines()]
    bars = [ax for ax in fig.axes if ax.patches]
    assert len(curves) == 2 and len(bars) == 2 and all(ax.get_legend() is None for ax in fig.axes)
    per_agent, per_window = ([p.get_height() for p in ax.patches] for ax in bars)
    assert sum(per_agent) == 30 * 2 + 30 * 5 and sum(per_window) == 60
    shown = [t.get_text() for ax in bars for t in ax.texts]
    assert shown == [str(int(h)) for h in per_agent + per_window]  # each bar says its count
    (key,) = fig.legends
    assert [t.get_text() for t in key.get_texts()][:2] == ["AgentFormer", "ForceFormer-Dr"]
    assert "K = 3" in fig._suptitle.get_text()
    plt.close(fig)


def test_the_maps_check_figure_has_a_key_entry_per_channel(tmp_path: Path) -> None:
    cfg = MapsConfig(resolution_m=0.25, margin_m=1.0, colour_clusters=3)
    raster, transform, images = build_scene(make_scene(tmp_path / "zara1"), cfg)
    fig = _check_figure_drawn("zara1", raster, images, transform)
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend()]
    assert len(legends) == 1
    labels = [t.get_text() for t in legends[0].get_texts()]
    assert len(labels) == len(raster) == 5
    assert [label.split()[0] for label in labels] == ["0", "1", "2", "3", "4"]
    assert labels[0].startswith("0 inside") and labels[1] == "1 obstacle: black outline"
    assert "darkest" in labels[2] and "lightest" in labels[4]
    drawn = [to_hex(c) for c in fig.axes[2].get_images()[0].get_cmap().colors]
    assert len(set(drawn)) == 1 + 3 and "#000000" not in drawn  # outside + one per cluster, never obstacle black
    plt.close(fig)
    # a cluster's swatches: the colour it is drawn in, then its mean image colour; the light region is 200 grey
    key = _channel_key(raster, images[1], drawn[1:])
    as_drawn, mean = key[4][0]
    assert to_hex(as_drawn.get_facecolor()) == drawn[-1] and "mean RGB (200, 200, 200)" in labels[4]
    assert np.allclose(to_rgb(mean.get_facecolor()), (200 / 255,) * 3, atol=0.01)
    _check_figure("zara1", raster, images, transform, tmp_path / "check.png")
    assert (tmp_path / "check.png").read_bytes()[:4] == b"\x89PNG"


def _error_bars(fig: plt.Figure) -> tuple[np.ndarray, np.ndarray]:
    """The minFDE curve's points (n, 2) and their error bars' end points (n, 2, 2)."""
    container = next(c for c in fig.axes[0].containers if isinstance(c, ErrorbarContainer))
    data_line, _, (bars,) = container.lines
    return data_line.get_xydata(), np.array(bars.get_segments())


def test_the_density_curves_carry_block_bootstrap_intervals_that_hold_their_means() -> None:
    """Each bin's point has an error bar around it; constant values give none; a slowly varying error over time
    (overlapping windows) gives wider bars with blocks of 20 windows than with windows drawn one by one."""
    data = recordings({"crowds_zara01": 200}, agents=3)
    drift = 1 + 0.5 * np.sin(np.arange(200) / 15)  # neighbouring windows alike, as stride-1 windows are
    frames = {"dr": evaluation(data, "dr", drift).frame}
    widths = {}
    for block in (1, 20):
        fig = plots.density_figure({"zara1": frames}, resampling=plots.Resampling(500, 0, block, 0.95))
        points, bars = _error_bars(fig)
        assert len(points) == len(bars) >= 1
        assert ((bars[:, 0, 1] <= points[:, 1]) & (points[:, 1] <= bars[:, 1, 1])).all()
        widths[block] = float((bars[:, 1, 1] - bars[:, 0, 1]).mean())
        plt.close(fig)
    assert widths[20] > 1.5 * widths[1] > 0
    fig = plots.density_figure({"zara1": {"dr": evaluation(data, "dr", np.ones(200)).frame}})
    _, bars = _error_bars(fig)
    np.testing.assert_allclose(bars[:, 0, 1], bars[:, 1, 1])  # every window alike: nothing to be unsure of
    plt.close(fig)
