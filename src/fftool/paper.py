"""The predictors' names in print, and the ForceFormer paper's published numbers (Tables II-IV) beside ours.

The baseline row is AgentFormer as quoted by the paper (its post-fix numbers). Table II lists only
AgentFormer, -Dr and -Re. What the predictors are: fftool.variants.
"""

from __future__ import annotations

from typing import Final

PAPER_NAMES: Final = {
    "cv": "constant velocity",
    "baseline": "AgentFormer",
    "goal": "ForceFormer-Goal",
    "dr": "ForceFormer-Dr",
    "re": "ForceFormer-Re",
}

# Table II: minADE_20 / minFDE_20 (m).
TABLE2_ADE_FDE: Final[dict[str, dict[str, tuple[float, float]]]] = {
    "baseline": {"eth": (0.45, 0.75), "hotel": (0.14, 0.22), "univ": (0.25, 0.45), "zara1": (0.18, 0.30),
                 "zara2": (0.14, 0.24), "average": (0.23, 0.39)},
    "dr": {"eth": (0.43, 0.58), "hotel": (0.12, 0.16), "univ": (0.21, 0.32), "zara1": (0.14, 0.20),
           "zara2": (0.12, 0.17), "average": (0.20, 0.29)},
    "re": {"eth": (0.36, 0.52), "hotel": (0.09, 0.14), "univ": (0.21, 0.42), "zara1": (0.15, 0.22),
           "zara2": (0.12, 0.20), "average": (0.19, 0.30)},
}  # fmt: skip

# Other methods' published minADE_20 / minFDE_20 (m), reference rows of Table II: printed as their papers report
# them, never re-run (research/peers-and-users.md §1a). AgentFormer's own are the baseline row's "(paper)" cells.
PUBLISHED_REFERENCES: Final[dict[str, dict[str, tuple[float, float]]]] = {
    "Y-net with TTST (ICCV'21), published, not re-run": {
        "eth": (0.28, 0.33), "hotel": (0.10, 0.14), "univ": (0.24, 0.41), "zara1": (0.17, 0.27),
        "zara2": (0.13, 0.22), "average": (0.18, 0.27),
    },
    "SingularTrajectory (CVPR'24), published, not re-run": {
        "eth": (0.35, 0.42), "hotel": (0.13, 0.19), "univ": (0.25, 0.44), "zara1": (0.19, 0.32),
        "zara2": (0.15, 0.25), "average": (0.21, 0.32),
    },
}  # fmt: skip

# Table III: minFDE_20 (m) per variant.
TABLE3_FDE: Final[dict[str, dict[str, float]]] = {
    "baseline": {"eth": 0.75, "hotel": 0.22, "univ": 0.45, "zara1": 0.30, "zara2": 0.24, "average": 0.39},
    "goal": {"eth": 0.55, "hotel": 0.17, "univ": 0.49, "zara1": 0.30, "zara2": 0.28, "average": 0.36},
    "dr": {"eth": 0.58, "hotel": 0.16, "univ": 0.32, "zara1": 0.20, "zara2": 0.17, "average": 0.29},
    "re": {"eth": 0.52, "hotel": 0.14, "univ": 0.42, "zara1": 0.22, "zara2": 0.20, "average": 0.30},
}

# Table IV: number of collisions (γ = 0.1 m, K = 20, best-ADE samples).
TABLE4_COLLISIONS: Final[dict[str, dict[str, int]]] = {
    "baseline": {"eth": 0, "hotel": 2, "univ": 655, "zara1": 4, "zara2": 22, "sum": 683},
    "goal": {"eth": 0, "hotel": 0, "univ": 672, "zara1": 3, "zara2": 22, "sum": 697},
    "dr": {"eth": 0, "hotel": 1, "univ": 556, "zara1": 3, "zara2": 28, "sum": 588},
    "re": {"eth": 0, "hotel": 1, "univ": 529, "zara1": 5, "zara2": 13, "sum": 548},
}
