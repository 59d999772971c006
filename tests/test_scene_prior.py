"""The goal U-Net's scene prior: occupancy counted by hand, the cross-fit that hides a window's own track, and
a goal U-Net that trains and samples with it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from fftool.config import GoalConfig
from fftool.learning import goal_model, scene_prior
from fftool.learning.batches import AgentWindows, SceneMaps

from .test_goal import TINY, _train, inputs  # noqa: F401  (the fixture)


def _maps() -> SceneMaps:
    """zara1's and univ's rasters, 10 × 10 cells of 1 m from the world origin, and the 'no map' scene."""
    return SceneMaps(torch.zeros(3, 2, 10, 10), torch.zeros(3, 2), 1.0, ("univ", "zara1"))


def _windows(rows: list[tuple[str, int, int, list[tuple[float, float]]]]) -> AgentWindows:
    xy = np.array([r[3] for r in rows], dtype=np.float64)
    n = len(rows)
    return AgentWindows(
        xy=xy,
        source=np.array([r[0] for r in rows]),
        first_step=np.array([r[2] for r in rows]),
        window_id=np.arange(n),
        ped_id=np.array([r[1] for r in rows]),
        row=np.arange(n),
    )


def test_occupancy_counts_each_position_once_on_every_map_of_its_place(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(scene_prior, "BLUR_CELLS", 0.0)  # counts as they are
    # Two overlapping windows of one zara3 walker (steps 0-1 and 1-2) and a standing uni_examples walker.
    tracks = _windows(
        [
            ("crowds_zara03", 1, 0, [(2.5, 3.5), (3.5, 3.5)]),
            ("crowds_zara03", 1, 1, [(3.5, 3.5), (4.5, 3.5)]),
            ("uni_examples", 7, 0, [(8.5, 8.5), (8.5, 8.5)]),
        ]
    )
    prior = scene_prior.occupancy(_maps(), tracks, np.ones(3, dtype=bool)).numpy()
    assert prior.shape == (3, 1, 10, 10)
    zara = np.zeros((10, 10), dtype=np.float32)
    zara[3, 2:5] = 1  # zara3 walks on zara1's map; the step both windows hold counts once
    univ = np.zeros((10, 10), dtype=np.float32)
    univ[8, 8] = 1  # uni_examples on univ's map (its two steps in one cell: the saturated maximum)
    assert np.array_equal(prior[1, 0], zara) and np.array_equal(prior[0, 0], univ)
    assert not prior[2].any()  # the 'no map' scene stays zero


def test_a_training_window_never_reads_its_own_track_and_validation_reads_every_track(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(scene_prior, "BLUR_CELLS", 0.0)
    walkers = [("crowds_zara01", ped, 0, [(1.5 + ped % 5, 2.5), (1.5 + ped % 5, 5.5)]) for ped in range(16)]
    walkers.append(("crowds_zara01", 99, 0, [(8.5, 2.5), (8.5, 5.5)]))  # alone in its column
    train = _windows(walkers)
    maps = scene_prior.with_prior(_maps(), train)
    assert maps.stack.shape == (3 * 3, 3, 10, 10) and len(maps.origins) == 9
    folds = scene_prior.track_folds(train)
    assert set(folds) == {0, 1}
    index = scene_prior.scene_index(maps, train, cross_fit=True)
    lit = []
    for i, (_, ped, _, xy) in enumerate(walkers):
        own = maps.stack[index[i], -1]
        col, row = int(xy[0][0]), int(xy[0][1])
        others_here = [j for j, w in enumerate(walkers) if int(w[3][0][0]) == col and folds[j] != folds[i]]
        assert (own[row, col] > 0) == bool(others_here), ped  # only another fold's walker lights the cell
        lit.append(bool(others_here))
    assert any(lit) and not all(lit)
    every = scene_prior.scene_index(maps, train, cross_fit=False)
    assert (every // 3 == scene_prior.ALL).all()
    assert int((maps.stack[every[0], -1] > 0).sum()) == 6 * 2  # every walker's two cells, both folds


def test_folds_do_not_depend_on_the_process() -> None:
    tracks = _windows([("students001", 3, 0, [(0, 0)]), ("biwi_eth", 3, 0, [(0, 0)])])
    assert scene_prior.track_folds(tracks).tolist() == [
        (__import__("zlib").crc32(b"students001") + 3) % 2,
        (__import__("zlib").crc32(b"biwi_eth") + 3) % 2,
    ]


def test_a_goal_unet_trains_and_samples_with_the_prior(inputs: dict, tmp_path: Path) -> None:  # noqa: F811
    cfg = TINY.model_copy(update={"epochs": 2, "scene_prior": "occupancy"})
    stats = _train(inputs, tmp_path, "prior", cfg)
    assert np.isfinite([row["train_loss"] for row in stats["log"]]).all()
    saved = torch.load(tmp_path / "prior" / "model.pt", weights_only=True)
    assert saved["in_channels"] == 8 + 6 + 1 and GoalConfig.model_validate(saved["config"]).scene_prior == "occupancy"
    maps = scene_prior.load_goal_scenes(inputs["maps"], inputs["windows"], "zara1", cfg)
    assert goal_model.input_channels(cfg, 8, maps.channels) == saved["in_channels"]
