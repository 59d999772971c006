"""Scene maps: the warp puts a world point in the right raster cell; fallbacks; check figures."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from fftool.config import MapsConfig
from fftool.errors import RawDataError
from fftool.stages.maps import build_scene, rasterise

# An affine world->pixel matrix like UCY's: 20 px per metre, y up, image 200 × 160.
MATRIX = np.array([[20.0, 0.0, 10.0], [0.0, -20.0, 150.0], [0.0, 0.0, 1.0]])


def make_scene(folder: Path, marker_world: tuple[float, float] = (3.0, 4.0)) -> Path:
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    image = np.full((160, 200, 3), 90, np.uint8) + rng.integers(0, 8, (160, 200, 3), dtype=np.uint8)
    image[:, 120:] = (200, 200, 200)  # a light region on the right
    cv2.imwrite(str(folder / "reference.png"), image)
    np.savetxt(folder / "world_to_pixel.txt", MATRIX)
    u, v, _ = MATRIX @ np.array([*marker_world, 1.0])
    obstacle = np.zeros((160, 200), np.uint8)
    obstacle[int(v) - 2 : int(v) + 3, int(u) - 2 : int(u) + 3] = 255  # a 5 px (0.25 m) block
    cv2.imwrite(str(folder / "obstacle_map.png"), obstacle)
    return folder


def test_a_world_point_lands_in_its_raster_cell(tmp_path: Path) -> None:
    cfg = MapsConfig(resolution_m=0.25, margin_m=1.0, colour_clusters=2)
    raster, transform, _ = build_scene(make_scene(tmp_path / "zara1"), cfg)
    assert transform["origin_x_m"] == pytest.approx(-0.5 - 1.0)  # image left edge x = -10/20 m, minus margin
    col = int((3.0 - transform["origin_x_m"]) / 0.25)
    row = int((4.0 - transform["origin_y_m"]) / 0.25)
    assert raster[1, row, col] == 1.0  # the obstacle block at world (3, 4)
    rows, cols = np.nonzero(raster[1])
    assert abs(rows.mean() - row) <= 1 and abs(cols.mean() - col) <= 1 and raster[1].sum() <= 4
    # round trip through the homography: the inside mask covers exactly the image footprint
    assert raster[0].sum() == pytest.approx((200 / 20) * (160 / 20) / 0.25**2, rel=0.05)
    # colour channels: one-hot inside, zero outside; the light right part is the lighter cluster
    assert np.array_equal(raster[2:].sum(0), raster[0])
    light_col = int((8.0 - transform["origin_x_m"]) / 0.25)
    assert raster[3, row, light_col] == 1.0


def test_missing_geometry_falls_back_and_bad_matrix_is_an_error(tmp_path: Path) -> None:
    make_scene(tmp_path / "scenes" / "zara1")
    out = tmp_path / "out"
    out.mkdir()
    stats = rasterise(MapsConfig(colour_clusters=2), tmp_path / "scenes", out)
    assert list(stats["scenes"]) == ["zara1"] and set(stats["without_geometry"]) == {"eth", "hotel", "univ", "zara2"}
    assert (out / "zara1.npy").is_file() and (out / "zara1_check.png").read_bytes()[:4] == b"\x89PNG"
    assert json.loads((out / "transforms.json").read_text())["channels"][:2] == ["inside", "obstacle"]
    (tmp_path / "scenes" / "zara1" / "world_to_pixel.txt").write_text("1 2\n3 4\n")
    with pytest.raises(RawDataError, match=r"world_to_pixel\.txt: expected an invertible 3×3"):
        rasterise(MapsConfig(colour_clusters=2), tmp_path / "scenes", out)


@pytest.mark.data
def test_real_scenes_are_warped_in_world_coordinates(real_raw: Path) -> None:
    scenes = real_raw.parent / "scenes"
    raster, transform, _ = build_scene(scenes / "eth", MapsConfig())
    trajectories = np.loadtxt(real_raw / "all_data" / "biwi_eth.txt")[:, 2:]
    cols = ((trajectories[:, 0] - transform["origin_x_m"]) / 0.25).astype(int)
    rows = ((trajectories[:, 1] - transform["origin_y_m"]) / 0.25).astype(int)
    # every eth position is inside the image footprint, and almost none on an obstacle (scenes/README.md)
    assert raster[0, rows, cols].mean() > 0.99
    assert raster[1, rows, cols].mean() < 0.02
