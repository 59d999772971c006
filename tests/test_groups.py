"""One DBSCAN call over all frames gives the same partition as one call per frame."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.cluster import DBSCAN

from fftool.science.groups import cluster_frames


def _partition(labels: np.ndarray) -> set[frozenset[int]]:
    """Clusters as sets of point indices; each noise point is its own singleton."""
    clusters: dict[int, set[int]] = {}
    for index, label in enumerate(labels):
        clusters.setdefault(int(label) if label >= 0 else -1 - index, set()).add(index)
    return {frozenset(c) for c in clusters.values()}


@pytest.mark.parametrize("min_samples", [1, 2, 3])
@pytest.mark.parametrize("seed", range(5))
def test_lifted_dbscan_equals_per_frame_dbscan(seed: int, min_samples: int) -> None:
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 12, size=300)
    xy = rng.uniform(0, 8, size=(300, 2))
    ours = cluster_frames(frames * 10 + 5, xy, 0.7, min_samples)
    expected = np.empty(300, dtype=np.int64)
    offset = 0
    for frame in np.unique(frames):
        members = np.flatnonzero(frames == frame)
        labels = DBSCAN(eps=0.7, min_samples=min_samples).fit_predict(xy[members])
        expected[members] = np.where(labels >= 0, labels + offset, -1)
        offset += labels.max() + 1
    assert _partition(ours) == _partition(expected)


def test_no_cluster_spans_two_frames() -> None:
    xy = np.zeros((4, 2))  # identical positions, different frames
    labels = cluster_frames(np.array([1, 1, 2, 2]), xy, 1.0, 2)
    assert labels[0] == labels[1] and labels[2] == labels[3] and labels[0] != labels[2]
