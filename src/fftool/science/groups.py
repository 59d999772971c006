"""Per-frame DBSCAN clusters of pedestrian positions (scikit-learn), all frames in one call.

DBSCAN on each frame separately would mean ~12,000 small calls. Instead every frame is lifted to its
own plane (a third coordinate far larger than eps), so one scikit-learn DBSCAN clusters all frames at
once and neighbourhoods never cross frames. Points keep their order within a frame, so the partition
equals that of separate per-frame runs (tests/test_groups.py checks it).
"""

from __future__ import annotations

import numpy as np


def cluster_frames(frame_key: np.ndarray, xy: np.ndarray, eps_m: float, min_samples: int) -> np.ndarray:
    """DBSCAN labels (N,) for points xy (N, 2) clustered separately per frame_key (N,); -1 is noise.

    Labels are unique across frames (a cluster never spans two frames). scikit-learn is imported here,
    not at module level: it pulls in scipy.stats (~2 s of CPU), which every other `fftool` command would
    pay at start-up.
    """
    from sklearn.cluster import DBSCAN

    if len(xy) == 0:
        return np.zeros(0, dtype=np.int64)
    _, frame_index = np.unique(frame_key, return_inverse=True)
    extent = float(np.ptp(xy, axis=0).max()) if len(xy) > 1 else 0.0
    separation = 10.0 * (extent + eps_m) + 1.0  # farther apart than any two points of one frame
    lifted = np.column_stack([xy, frame_index * separation])
    return DBSCAN(eps=eps_m, min_samples=min_samples).fit_predict(lifted).astype(np.int64)
