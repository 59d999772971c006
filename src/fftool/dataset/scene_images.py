"""A scene's reference image and world->pixel homography: read, checked, and used to project points.

Shared by the maps stage (rasters), the figures (trajectories over the image) and `forces --explain`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from fftool.errors import RawDataError


def read_homography(path: Path) -> np.ndarray:
    """A scene's world->pixel matrix, checked: 3×3, finite and invertible (RawDataError otherwise)."""
    try:
        matrix = np.loadtxt(path)
    except ValueError as exc:
        raise RawDataError(path, f"expected a 3×3 matrix of numbers ({exc})") from exc
    if matrix.shape != (3, 3) or not np.isfinite(matrix).all() or abs(np.linalg.det(matrix)) < 1e-12:
        raise RawDataError(path, f"expected an invertible 3×3 world->pixel matrix, found shape {matrix.shape}")
    return matrix


def apply_homography(matrix: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(..., 2) points through a 3×3 homography: p = M [x, y, 1], (u, v) = p[:2] / p[2]."""
    homogeneous = np.concatenate([xy, np.ones((*xy.shape[:-1], 1))], axis=-1) @ matrix.T
    return homogeneous[..., :2] / homogeneous[..., 2:3]


def read_image(path: Path, flags: int) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise RawDataError(path, "not a readable image")
    return image


@dataclass(frozen=True)
class SceneImage:
    """A scene's reference image (H, W, 3 RGB) and its world->pixel homography (3, 3)."""

    image: np.ndarray
    homography: np.ndarray


def read_scene(scene_dir: Path) -> SceneImage | None:
    """The image and homography of a scene folder; None when it lacks either file (a scene without geometry:
    its crops get no map and its figures are drawn in metres)."""
    image, matrix = scene_dir / "reference.png", scene_dir / "world_to_pixel.txt"
    if not (image.is_file() and matrix.is_file()):
        return None
    homography = read_homography(matrix)
    return SceneImage(cv2.cvtColor(read_image(image, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB), homography)


def project(scene: SceneImage | None, xy: np.ndarray) -> np.ndarray:
    """(..., 2) world metres -> pixels of the scene's image; the metres unchanged for a scene without one."""
    return xy if scene is None else apply_homography(scene.homography, xy)
