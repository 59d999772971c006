"""Raw Social-GAN parsing: round trip, fast/slow path agreement, and every bad-input rule."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fftool.errors import RawDataError
from fftool.rawfiles import _read_slow, read_raw

from .conftest import walker_rows, write_rows


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
