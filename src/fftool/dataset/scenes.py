"""ETH/UCY facts as typed constants: sources, benchmarks, the leave-one-out split, time base.

Every number that describes the dataset lives here, so a reader finds the protocol on one page.
"""

from __future__ import annotations

from typing import Final, Literal, get_args

# Time base. Raw frame ids step by 10 in every Social-GAN file; one step is 0.4 s (2.5 Hz).
# Known quirk: the ETH (biwi_eth) recording's real step is about 0.667 s (its annotations were made
# every 6 video frames and re-numbered), but the community, and therefore the benchmark numbers,
# treat every step as 0.4 s. We keep 0.4 s and record it in every manifest (docs/data.md).
FRAME_STRIDE: Final[int] = 10
DT_S: Final[float] = 0.4

OBS_LEN: Final[int] = 8  # observed steps t = -7..0
PRED_LEN: Final[int] = 12  # predicted steps t = 1..12
WINDOW_LEN: Final[int] = OBS_LEN + PRED_LEN

# The eight Social-GAN sources. crowds_zara03 and uni_examples are only ever used for training.
SOURCES: Final[tuple[str, ...]] = (
    "biwi_eth",
    "biwi_hotel",
    "crowds_zara01",
    "crowds_zara02",
    "crowds_zara03",
    "students001",
    "students003",
    "uni_examples",
)

# A raw file is one "split" of a source: the whole recording, or its first (train) / last (val) part
# in time. train + val = all, row for row.
Split = Literal["all", "train", "val"]
SPLITS: Final[tuple[Split, ...]] = get_args(Split)
SPLIT_DIRS: Final[dict[str, str]] = {"all": "all_data", "train": "train", "val": "val"}
SPLIT_SUFFIX: Final[dict[str, str]] = {"all": "", "train": "_train", "val": "_val"}

# The five benchmark scenes and the sources that make up each one's test part.
Benchmark = Literal["eth", "hotel", "univ", "zara1", "zara2"]
BENCHMARKS: Final[tuple[Benchmark, ...]] = get_args(Benchmark)
BENCHMARK_TEST_SOURCES: Final[dict[Benchmark, tuple[str, ...]]] = {
    "eth": ("biwi_eth",),
    "hotel": ("biwi_hotel",),
    "univ": ("students001", "students003"),  # uni_examples stays in training, as in AgentFormer
    "zara1": ("crowds_zara01",),
    "zara2": ("crowds_zara02",),
}

Part = Literal["train", "val", "test"]
PARTS: Final[tuple[Part, ...]] = get_args(Part)


def raw_relpath(source: str, split: str) -> str:
    """Path of one raw file relative to the raw root, e.g. `train/biwi_eth_train.txt`."""
    return f"{SPLIT_DIRS[split]}/{source}{SPLIT_SUFFIX[split]}.txt"


def _leave_one_out() -> dict[str, dict[str, tuple[tuple[str, str], ...]]]:
    """The leave-one-out table (Social-GAN, Trajectron++, AgentFormer; DESIGN §2).

    test = the full files of the held-out scene; train/val = the `_train`/`_val` files of every
    source that is not part of the held-out scene.
    """
    table: dict[str, dict[str, tuple[tuple[str, str], ...]]] = {}
    for benchmark, test_sources in BENCHMARK_TEST_SOURCES.items():
        others = tuple(s for s in SOURCES if s not in test_sources)
        table[benchmark] = {
            "train": tuple((s, "train") for s in others),
            "val": tuple((s, "val") for s in others),
            "test": tuple((s, "all") for s in test_sources),
        }
    return table


# LEAVE_ONE_OUT[benchmark][part] = ((source, split), ...): the raw files that make up that part.
LEAVE_ONE_OUT: Final[dict[str, dict[str, tuple[tuple[str, str], ...]]]] = _leave_one_out()


# Scene geometry (scenes/<scene>/reference.png + world_to_pixel.txt) for each source. crowds_zara03
# has no image of its own; the scenes README finds its trajectories plausible on the zara2 image
# (same camera), so it shares zara2's map. uni_examples has no image: its trajectories cross objects of the
# students03 image (probably another view), so it has no map. Goal-SAR gives it univ's; on univ's validation
# that made no difference (docs/experiments/goal-levers.md).
SOURCE_SCENE: Final[dict[str, str | None]] = {
    "biwi_eth": "eth",
    "biwi_hotel": "hotel",
    "crowds_zara01": "zara1",
    "crowds_zara02": "zara2",
    "crowds_zara03": "zara2",
    "students001": "univ",
    "students003": "univ",
    "uni_examples": None,
}
SCENES: Final[tuple[str, ...]] = BENCHMARKS  # one scene folder per benchmark, named after it


def scene_of(source: str) -> str | None:
    """The scene (map) of a tracks source: SOURCE_SCENE for ETH/UCY; a dataset's source `<name>/<file>`
    (fftool.dataset.custom) belongs to the dataset's one scene, its name."""
    if source in SOURCE_SCENE:
        return SOURCE_SCENE[source]
    return source.split("/", 1)[0] if "/" in source else None


# Published goal-module FDE@20 (m) on ETH/UCY: the targets for the goal estimator alone
# (research/goal_module.md §5.3; both take the best of 20 goals, independently of the ADE minimum).
PUBLISHED_GOAL_FDE20: Final[dict[str, dict[str, float]]] = {
    "Y-net": {"eth": 0.33, "hotel": 0.14, "univ": 0.41, "zara1": 0.27, "zara2": 0.22, "average": 0.27},
    "Goal-SAR": {"eth": 0.39, "hotel": 0.17, "univ": 0.43, "zara1": 0.26, "zara2": 0.22, "average": 0.29},
}
