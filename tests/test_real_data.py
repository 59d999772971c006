"""The real ETH/UCY files: row counts, the leave-one-out table, and the benchmark's window counts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from fftool import pipeline
from fftool.artifacts.schema import AGENT_WINDOWS_FILE, TRACKS_FILE, WINDOWS_FILE
from fftool.artifacts.store import ArtifactStore
from fftool.config import load_config
from fftool.dataset.scenes import LEAVE_ONE_OUT

pytestmark = pytest.mark.data

# Rows per raw file (all_data), checked independently with wc -l.
ROWS = {
    "biwi_eth": 5492,
    "biwi_hotel": 6543,
    "crowds_zara01": 5153,
    "crowds_zara02": 9722,
    "crowds_zara03": 5005,
    "students001": 21813,
    "students003": 17953,
    "uni_examples": 2747,
}
# Test parts: (windows with a valid agent, valid agent-windows). The agent-window counts are the
# "valid trajectories" of the ForceFormer paper and AgentFormer's ADE/FDE denominators.
TEST_COUNTS = {
    "eth": (253, 364),
    "hotel": (445, 1197),
    "univ": (947, 24334),
    "zara1": (705, 2356),
    "zara2": (998, 5910),
}


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> dict:
    from .conftest import REAL_RAW

    if not REAL_RAW.is_dir():
        pytest.skip("real data absent")  # the real_raw fixture below fails instead when CI requires data
    cfg = load_config(None, [f"data.raw_dir={str(REAL_RAW.resolve())!r}"])
    return pipeline.run(cfg, ArtifactStore(tmp_path_factory.mktemp("art")), ["forces"])


def test_every_raw_file_is_ingested(real_raw: Path, built: dict) -> None:
    tracks = pq.read_table(built["tracks"].file(TRACKS_FILE)).to_pandas()
    counts = tracks[tracks["split"] == "all"].groupby("source", observed=True).size().to_dict()
    assert counts == ROWS
    assert (tracks["step"] * 10 == tracks["frame_id"]).all()
    assert built["tracks"].manifest.stats["warnings"] == []


@pytest.mark.parametrize("benchmark", sorted(TEST_COUNTS))
def test_test_part_window_counts(real_raw: Path, built: dict, benchmark: str) -> None:
    summary = {(r["benchmark"], r["part"]): r for r in built["windows"].manifest.stats["summary"]}
    row = summary[(benchmark, "test")]
    assert (row["windows"], row["agent_windows"]) == TEST_COUNTS[benchmark]


def test_eth_train_matches_agentformer_iterations(real_raw: Path, built: dict) -> None:
    # research/agentformer.md §6: 4843 candidate frames, 3283 non-empty scenes, 30,307 agent-windows.
    row = next(r for r in built["windows"].manifest.stats["summary"] if (r["benchmark"], r["part"]) == ("eth", "train"))
    assert (row["candidate_windows"], row["windows"], row["agent_windows"]) == (4843, 3283, 30307)


def test_leave_one_out_never_trains_on_the_test_scene() -> None:
    for benchmark, parts in LEAVE_ONE_OUT.items():
        test_sources = {source for source, _ in parts["test"]}
        assert test_sources.isdisjoint(source for source, _ in parts["train"] + parts["val"]), benchmark
        assert {split for _, split in parts["train"]} == {"train"}
        assert len(parts["train"]) + len(test_sources) == 8


def test_agent_window_positions_match_the_raw_file(real_raw: Path, built: dict) -> None:
    windows = pq.read_table(built["windows"].file(WINDOWS_FILE)).to_pandas()
    agents = pq.read_table(built["windows"].file(AGENT_WINDOWS_FILE), filters=[("benchmark", "=", "zara1")]).to_pandas()
    test = agents[agents["part"] == "test"].iloc[::97]
    raw = np.loadtxt(real_raw / "all_data" / "crowds_zara01.txt")
    lookup = {(int(f), int(p)): (x, y) for f, p, x, y in raw}
    zara1 = windows[(windows["benchmark"] == "zara1") & (windows["part"] == "test")].set_index("window_id")
    for _, row in test.iterrows():
        first = zara1.loc[row["window_id"], "first_step"]
        expected = [lookup[((first + t) * 10, row["ped_id"])] for t in range(20)]
        np.testing.assert_array_equal(np.asarray(row["xy"]).reshape(20, 2), expected)


def test_forces_on_every_agent_window(real_raw: Path, built: dict) -> None:
    windows = {(r["benchmark"], r["part"]): r["agent_windows"] for r in built["windows"].manifest.stats["summary"]}
    summary = built["forces"].manifest.stats["summary"]
    assert {(r["benchmark"], r["part"]): r["agent_windows"] for r in summary} == windows
    for row in summary:
        assert 0.05 < row["mean_abs_f_dr"] < 2.0, row  # m/s², a walking pace corrected over tau = 0.5 s
        assert 0.0 < row["mean_abs_f_re"] < row["mean_abs_f_dr"], row
        assert 0.0 < row["grouped_pair_share"] < 0.5, row
    f_dr = np.load(built["forces"].file("f_dr.npy"), mmap_mode="r")
    assert np.isfinite(f_dr).all() and (f_dr[:, -1] == 0).all()  # at the goal: no driving force


def test_explain_draws_on_the_real_scene(real_raw: Path, built: dict, tmp_path: Path) -> None:
    from fftool.reporting.explain import explain_window

    png = explain_window(
        scene="zara2",
        frame_id=5720,
        out=tmp_path / "zara2.png",
        windows=built["windows"],
        forces=built["forces"],
        tracks=built["tracks"],
        scenes_dir=real_raw.parent / "scenes",
    )
    import matplotlib.image

    assert matplotlib.image.imread(png).shape[0] > 500  # drawn over the 720×576 reference image
