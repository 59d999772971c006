"""Raw Social-GAN parsing: round trip, fast/slow path agreement, and every bad-input rule."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fftool.artifacts.schema import TRACKS_FILE
from fftool.config import IngestConfig
from fftool.dataset.rawfiles import RawTable, _read_fast, _read_slow, read_raw
from fftool.dataset.windowing import slice_sequence
from fftool.errors import RawDataError
from fftool.stages import tracks

from .conftest import walker_rows, write_rows

INT64_RANGE = "(-9223372036854775808 to 9223372036854775807)"


@settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None)
@given(
    data=st.lists(
        st.tuples(
            st.integers(0, 500),
            st.integers(1, 40),
            st.floats(-50, 50, allow_nan=False).map(lambda v: round(v, 3)),
            st.floats(-50, 50, allow_nan=False).map(lambda v: round(v, 3)),
        ),
        min_size=1,
        max_size=60,
        unique_by=lambda r: (r[0], r[1]),
    ),
    sep=st.sampled_from(["\t", " ", "  ", " \t "]),
)
def test_round_trip_any_whitespace(tmp_path: Path, data: list[tuple[int, int, float, float]], sep: str) -> None:
    rows = [(frame * 10, ped, x, y) for frame, ped, x, y in data]
    path = write_rows(tmp_path / "scene.txt", rows, sep=sep)
    table = read_raw(path, frame_stride=10)
    assert table.frame_id.tolist() == [r[0] for r in rows]
    assert table.ped_id.tolist() == [r[1] for r in rows]
    assert table.x.tolist() == [r[2] for r in rows]
    assert table.y.tolist() == [r[3] for r in rows]
    slow = _read_slow(path, 10, "warn")
    for name in ("frame_id", "ped_id", "x", "y"):
        np.testing.assert_array_equal(getattr(slow, name), getattr(table, name))


def test_float_formatted_ids_and_blank_lines_are_accepted(tmp_path: Path) -> None:
    path = tmp_path / "scene.txt"
    path.write_text("0.0\t1.0\t1.5\t2.5\n\n10.0 1.0 1.6 2.6\n   \n")
    table = read_raw(path, frame_stride=10)
    assert table.frame_id.tolist() == [0, 10] and table.ped_id.dtype == np.int64


BAD_CASES = {
    "non-numeric": ("0 1 1.0 2.0\n10 1 abc 2.0\n", 2, "x is not a number: 'abc'"),
    "too many fields": ("0 1 1.0 2.0\n10 1 1.0 2.0 7\n", 2, "expected 4 fields `frame_id ped_id x y`, found 5"),
    "too few fields": ("0 1 1.0 2.0\n10 1 1.0\n", 2, "expected 4 fields `frame_id ped_id x y`, found 3"),
    "nan": ("0 1 1.0 2.0\n10 1 nan 2.0\n", 2, "x must be finite, found 'nan'"),
    "inf": ("0 1 1.0 2.0\n10 1 1.0 -inf\n", 2, "y must be finite, found '-inf'"),
    "header": ("frame ped x y\n0 1 1.0 2.0\n", 1, "frame_id is not a number: 'frame'"),
    "fractional frame": ("0 1 1.0 2.0\n10.5 1 1.0 2.0\n", 2, "frame_id must be an integer, found 10.5"),
    "fractional ped": ("0 1 1.0 2.0\n10 3.5 1.0 2.0\n", 2, "ped_id must be an integer, found 3.5"),
    "fractional ped beyond 2**53": (
        "0 1 1.0 2.0\n10 9007199254740993.5 1.0 2.0\n",
        2,
        "ped_id must be an integer, found '9007199254740993.5'",
    ),
    "frame 1e20": (
        "0 1 1.0 2.0\n1e20 1 1.0 2.0\n",
        2,
        f"frame_id must be an integer within int64 {INT64_RANGE}, found '1e20'",
    ),
    "ped above int64": (
        "0 1 1.0 2.0\n10 9223372036854775808 1.0 2.0\n",
        2,
        f"ped_id must be an integer within int64 {INT64_RANGE}, found '9223372036854775808'",
    ),
    "ped below int64": (
        "0 1 1.0 2.0\n10 -9223372036854775809 1.0 2.0\n",
        2,
        f"ped_id must be an integer within int64 {INT64_RANGE}, found '-9223372036854775809'",
    ),
    "frame nan": ("0 1 1.0 2.0\nnan 1 1.0 2.0\n", 2, "frame_id must be finite, found 'nan'"),
    "ped inf": ("0 1 1.0 2.0\n10 inf 1.0 2.0\n", 2, "ped_id must be finite, found 'inf'"),
    "x overflows float64": ("0 1 1.0 2.0\n10 1 1e400 2.0\n", 2, "x must be finite, found '1e400'"),
    "off stride": (
        "0 1 1.0 2.0\n10 1 1.1 2.0\n25 1 1.2 2.0\n",
        3,
        "frame_id 25 is off the frame stride 10 (earlier frame ids are ≡ 0 mod 10)",
    ),
    "different duplicate": (
        "0 1 1.0 2.0\n0 2 3.0 2.0\n0 1 1.5 2.0\n",
        3,
        "duplicate row for frame_id 0, ped_id 1 with a different position (first at line 1)",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input_names_file_and_line(tmp_path: Path, case: str) -> None:
    text, line_no, problem = BAD_CASES[case]
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(RawDataError) as info:
        read_raw(path, frame_stride=10)
    assert str(info.value) == f"{path}:{line_no}: {problem}"


@pytest.mark.parametrize("text", ["", "\n\n  \n"])
def test_empty_file_is_an_error(tmp_path: Path, text: str) -> None:
    path = tmp_path / "empty.txt"
    path.write_text(text)
    with pytest.raises(RawDataError, match=r"empty\.txt: file is empty"):
        read_raw(path, frame_stride=10)


def test_missing_file_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(RawDataError, match=r"nope\.txt: file not found"):
        read_raw(tmp_path / "nope.txt", frame_stride=10)


def test_binary_file_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "bin.txt"
    path.write_bytes(b"\xff\xfe\x00\x01garbage")
    with pytest.raises(RawDataError, match=r"bin\.txt"):
        read_raw(path, frame_stride=10)


def test_identical_duplicate_is_a_warning_and_dropped(tmp_path: Path) -> None:
    path = tmp_path / "dup.txt"
    path.write_text("0 1 1.0 2.0\n0 2 3.0 2.0\n0 1 1.0 2.0\n10 1 1.1 2.0\n")
    table = read_raw(path, frame_stride=10, duplicates="warn")
    assert len(table) == 3
    assert table.warnings == [f"{path}:3: identical duplicate of line 1 (frame_id 0, ped_id 1) dropped"]


def test_identical_duplicate_is_an_error_when_strict(tmp_path: Path) -> None:
    path = tmp_path / "dup.txt"
    path.write_text("0 1 1.0 2.0\n0 1 1.0 2.0\n")
    with pytest.raises(RawDataError, match=r"dup\.txt:2: duplicate row .* with the same position"):
        read_raw(path, frame_stride=10, duplicates="error")


def test_stride_phase_may_be_non_zero(tmp_path: Path) -> None:
    path = write_rows(tmp_path / "s.txt", [(5, 1, 0.0, 0.0), (15, 1, 0.1, 0.0)])
    assert read_raw(path, frame_stride=10).frame_id.tolist() == [5, 15]


def test_walker_fixture_parses(tmp_path: Path) -> None:
    rows = walker_rows(4, 30)
    table = read_raw(write_rows(tmp_path / "w.txt", rows), frame_stride=10)
    assert len(table) == len(rows)


def test_ids_at_the_int64_limits_and_beyond_float64_precision_are_exact(tmp_path: Path) -> None:
    # float64 cannot tell 2**53 from 2**53 + 1: these must stay two pedestrians, not a duplicate.
    path = tmp_path / "big.txt"
    path.write_text(
        "0 9223372036854775807 1.0 2.0\n0 -9223372036854775808 1.0 2.0\n"
        "0 9007199254740992 1.0 2.0\n0 9007199254740993.0 1.0 2.0\n"
    )
    table = read_raw(path, frame_stride=10)
    assert table.ped_id.dtype == np.int64 and table.warnings == []
    assert table.ped_id.tolist() == [2**63 - 1, -(2**63), 2**53, 2**53 + 1]


def _mixed_whitespace(text: str) -> str:
    """Leading spaces, runs of spaces, tabs among spaces and trailing blanks, varying line to line."""
    seps = ("   ", " \t  ", "\t\t")
    return "".join(
        " " * (i % 3) + line.replace("\t", seps[i % 3]) + "\t \n" for i, line in enumerate(text.splitlines())
    )


CLEAN = "0\t1\t1.0\t2.0\n0\t2\t3.0\t2.5\n10\t1\t1.1\t2.0\n10\t2\t3.1\t2.5\n"
CONTENTS = {
    "clean": CLEAN,  # the fast path
    "identical duplicate": CLEAN + "0\t2\t3.0\t2.5\n",  # the slow path (warning)
    "ids beyond 2**53": CLEAN.replace("\t2\t", "\t9007199254740993\t"),  # the slow path (exact ids)
}
VARIANTS = {
    "bom": lambda text: "\ufeff" + text,
    "crlf": lambda text: text.replace("\n", "\r\n"),
    "cr": lambda text: text.replace("\n", "\r"),
    "mixed whitespace": _mixed_whitespace,
    "all at once": lambda text: "\ufeff \t" + text.replace("\t", "  \t").replace("\n", " \r\n"),
}


def _same_table(got: RawTable, want: RawTable) -> None:
    for name in ("frame_id", "ped_id", "x", "y"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), strict=True)
    assert [w.replace(str(got.path), "<file>") for w in got.warnings] == [
        w.replace(str(want.path), "<file>") for w in want.warnings
    ]


@pytest.mark.parametrize("content", sorted(CONTENTS))
@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_bom_line_ends_and_whitespace_parse_like_the_clean_file(tmp_path: Path, content: str, variant: str) -> None:
    clean = tmp_path / "clean.txt"
    clean.write_bytes(CONTENTS[content].encode())
    odd = tmp_path / "odd.txt"
    odd.write_bytes(VARIANTS[variant](CONTENTS[content]).encode())
    assert odd.read_bytes() != clean.read_bytes()
    want = read_raw(clean, frame_stride=10)
    _same_table(read_raw(odd, frame_stride=10), want)
    _same_table(_read_slow(odd, 10, "warn"), want)  # the line-by-line pass agrees too
    assert (_read_fast(odd, 10) is None) == (_read_fast(clean, 10) is None)  # and takes the same path


def test_bom_crlf_and_tabs_give_identical_tracks(tmp_path: Path, raw_tree: Path) -> None:
    # One duplicate row sends a file through the slow path; a BOM used to turn it into an error.
    dup = next(raw_tree.rglob("*_train.txt"))
    dup.write_text(dup.read_text() + dup.read_text().splitlines()[0] + "\n")
    odd_tree = tmp_path / "odd"
    for path in raw_tree.rglob("*.txt"):
        target = odd_tree / path.relative_to(raw_tree)
        target.parent.mkdir(parents=True, exist_ok=True)
        text = path.read_text().replace("\t", " \t  ").replace("\n", "\r\n")
        target.write_bytes(("\ufeff" + text).encode())
    cfg = IngestConfig()
    results = []
    for root, out in ((raw_tree, tmp_path / "out_clean"), (odd_tree, tmp_path / "out_odd")):
        out.mkdir()
        stats = tracks.ingest_raw(cfg, root, out)
        stats["warnings"] = [w.replace(str(root), "<raw>") for w in stats["warnings"]]
        results.append((stats, pq.read_table(out / TRACKS_FILE)))
    (clean_stats, clean_tracks), (odd_stats, odd_tracks) = results
    assert clean_stats == odd_stats and len(clean_stats["warnings"]) >= 1
    assert odd_tracks.equals(clean_tracks)
    assert tracks.raw_input_hashes(odd_tree) != tracks.raw_input_hashes(raw_tree)  # bytes differ, tracks do not


def test_a_far_off_frame_id_does_not_size_the_windows_by_the_gap() -> None:
    # Any int64 frame id passes ingest; a gap of ~1e17 steps must not allocate peds × gap presence arrays.
    far = 9 * 10**17
    step = np.r_[np.arange(25), far + np.arange(25)].astype(np.int64)
    ped_id = np.repeat(np.array([1, 2], np.int64), 25)
    result = slice_sequence(step, ped_id, step * 10, np.zeros((50, 2)), window_len=20, obs_len=8)
    assert result.first_step.tolist() == [*range(6), *range(far, far + 6)]
    assert result.n_present.tolist() == [1] * 12 and result.n_agents.tolist() == [1] * 12


def test_ingest_stats_are_exact_for_ids_across_the_whole_int64_range(raw_tree: Path, tmp_path: Path) -> None:
    low, high = -(2**63) + 10, 2**63 - 6  # both ≡ 2 mod 10; their gap does not fit in int64
    path = raw_tree / "all_data" / "biwi_eth.txt"
    path.write_text(f"{low} {2**63 - 1} 1.0 2.0\n{high} {-(2**63)} 1.5 2.0\n")
    stats = tracks.ingest_raw(IngestConfig(), raw_tree, tmp_path)
    file = stats["files"]["all_data/biwi_eth.txt"]
    assert (file["first_frame_id"], file["last_frame_id"], file["observed_stride"]) == (low, high, high - low)
    table = pq.read_table(tmp_path / TRACKS_FILE).to_pandas()
    rows = table[(table["source"] == "biwi_eth") & (table["split"] == "all")]
    assert rows["ped_id"].tolist() == [2**63 - 1, -(2**63)] and rows["step"].tolist() == [low // 10, high // 10]
