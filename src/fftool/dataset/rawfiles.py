"""Read and validate raw Social-GAN text files (`frame_id ped_id x y`, any whitespace).

Validation is fast in the common case and precise in the rare one: pandas' C parser reads the file
and vectorised checks look for trouble; only when something is wrong does a line-by-line pass run to
name the exact line and problem. Both paths return identical tables for a clean file.

Ids (frame_id, ped_id) are integers within int64, written plainly or with a zero fraction (`780.0`);
anything else (`3.5`, `1e20`, `nan`) is an error, never a silent wrap. float64 holds every integer
below 2**53 exactly, so the fast path reads ids as floats and leaves larger ones to the slow path,
which reads them from their text. A UTF-8 byte-order mark, CRLF or CR line ends and any mix of tabs
and spaces parse exactly like the clean file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd

from fftool.errors import RawDataError

COLUMNS = ("frame_id", "ped_id", "x", "y")
INT64 = np.iinfo(np.int64)
# Below this magnitude float64 holds every integer exactly; ids at or beyond it are read from their text.
EXACT_FLOAT_INT = 2.0**53


@dataclass
class RawTable:
    """One validated raw file: integer ids, float positions, one row per (frame_id, ped_id)."""

    path: Path
    frame_id: np.ndarray  # (N,) int64
    ped_id: np.ndarray  # (N,) int64
    x: np.ndarray  # (N,) float64, metres
    y: np.ndarray  # (N,) float64, metres
    warnings: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.frame_id)


def read_raw(path: Path, frame_stride: int, duplicates: Literal["warn", "error"] = "warn") -> RawTable:
    """Parse and validate one raw file; raise `RawDataError` naming the file and line on bad input."""
    if not path.is_file():
        raise RawDataError(path, "file not found")
    table = _read_fast(path, frame_stride)
    if table is None:
        table = _read_slow(path, frame_stride, duplicates)
    if len(table) == 0:
        raise RawDataError(path, "file is empty: expected rows of `frame_id ped_id x y`")
    return table


def _read_fast(path: Path, frame_stride: int) -> RawTable | None:
    """pandas C parser + vectorised checks; None whenever anything looks wrong."""
    try:
        # pandas skips a leading UTF-8 BOM and accepts \n, \r\n and \r line ends.
        frame = pd.read_csv(path, sep=r"\s+", header=None, dtype=np.float64, engine="c", encoding="utf-8")
    except (ValueError, pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError):
        return None
    if frame.shape[1] != len(COLUMNS) or len(frame) == 0:
        return None
    values = frame.to_numpy()
    if not np.isfinite(values).all():
        return None
    ids = values[:, :2]
    if not ((np.abs(ids) < EXACT_FLOAT_INT) & (np.round(ids) == ids)).all():
        return None
    frame_id = ids[:, 0].astype(np.int64)
    ped_id = ids[:, 1].astype(np.int64)
    if (frame_id % frame_stride != frame_id.min() % frame_stride).any():
        return None
    keys = pd.MultiIndex.from_arrays([frame_id, ped_id])
    if keys.has_duplicates:
        return None
    return RawTable(path, frame_id, ped_id, values[:, 2].copy(), values[:, 3].copy())


def _read_slow(path: Path, frame_stride: int, duplicates: Literal["warn", "error"]) -> RawTable:
    """Line-by-line parse that stops at the first problem with its line number."""
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()  # -sig: a leading BOM is not data
    except UnicodeDecodeError as exc:
        raise RawDataError(path, f"not a text file ({exc.reason} at byte {exc.start})") from exc
    rows: list[tuple[int, int, float, float]] = []
    seen: dict[tuple[int, int], tuple[int, float, float]] = {}
    warnings: list[str] = []
    phase: int | None = None
    for line_no, line in enumerate(lines, start=1):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != len(COLUMNS):
            raise RawDataError(path, f"expected 4 fields `frame_id ped_id x y`, found {len(fields)}", line_no)
        numbers = []
        for name, text in zip(COLUMNS, fields):
            try:
                value = float(text)
            except ValueError:
                raise RawDataError(path, f"{name} is not a number: {text!r}", line_no) from None
            if not math.isfinite(value):
                raise RawDataError(path, f"{name} must be finite, found {text!r}", line_no)
            numbers.append(value)
        frame_id = _exact_id(path, line_no, "frame_id", fields[0], numbers[0])
        ped_id = _exact_id(path, line_no, "ped_id", fields[1], numbers[1])
        x, y = numbers[2], numbers[3]
        if phase is None:
            phase = frame_id % frame_stride
        elif frame_id % frame_stride != phase:
            raise RawDataError(
                path,
                f"frame_id {frame_id} is off the frame stride {frame_stride} "
                f"(earlier frame ids are ≡ {phase} mod {frame_stride})",
                line_no,
            )
        key = (frame_id, ped_id)
        if key in seen:
            first_line, fx, fy = seen[key]
            if (fx, fy) != (x, y) or duplicates == "error":
                same = "with the same" if (fx, fy) == (x, y) else "with a different"
                raise RawDataError(
                    path,
                    f"duplicate row for frame_id {frame_id}, ped_id {ped_id} {same} position "
                    f"(first at line {first_line})",
                    line_no,
                )
            warnings.append(
                f"{path}:{line_no}: identical duplicate of line {first_line} (frame_id {frame_id}, "
                f"ped_id {ped_id}) dropped"
            )
            continue
        seen[key] = (line_no, x, y)
        rows.append((frame_id, ped_id, x, y))
    if not rows:
        raise RawDataError(path, "file is empty: expected rows of `frame_id ped_id x y`")
    frame_ids, ped_ids, xs, ys = (np.array(col) for col in zip(*rows))
    return RawTable(
        path,
        frame_ids.astype(np.int64),
        ped_ids.astype(np.int64),
        xs.astype(np.float64),
        ys.astype(np.float64),
        warnings,
    )


def _exact_id(path: Path, line_no: int, name: str, text: str, value: float) -> int:
    """The id a field holds, exactly: its float where float64 is exact, else its text (no silent rounding)."""
    if value != round(value):
        raise RawDataError(path, f"{name} must be an integer, found {value!r}", line_no)
    if abs(value) < EXACT_FLOAT_INT:
        return int(value)
    try:
        exact = Decimal(text)
    except InvalidOperation:
        raise RawDataError(path, f"{name} is not a number: {text!r}", line_no) from None
    if exact != exact.to_integral_value():
        raise RawDataError(path, f"{name} must be an integer, found {text!r}", line_no)
    if not INT64.min <= exact <= INT64.max:
        raise RawDataError(
            path, f"{name} must be an integer within int64 ({INT64.min} to {INT64.max}), found {text!r}", line_no
        )
    return int(exact)
