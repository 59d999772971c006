"""A user's own trajectory file (CSV or Parquet: time or frame, agent id, x, y), read and checked.

Shared by `fftool predict` (observed tracks) and custom datasets (`fftool ingest` with a dataset TOML),
so both accept the same files and refuse bad ones with the same one-line errors: the file, the line
(CSV: counting the header as line 1) or column, and what was expected. Positions come out in metres,
times in seconds.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import pandas as pd

from fftool.errors import RawDataError

UNITS: Final = {"m": 1.0, "cm": 0.01, "mm": 0.001}  # metres per unit
# Column names tried in order when none is given: a time column in seconds, or a frame number.
TIME_COLUMNS: Final = ("time", "t", "timestamp", "frame", "frame_id")
FRAME_COLUMNS: Final = ("frame", "frame_id")
AGENT_COLUMNS: Final = ("agent_id", "agent", "ped_id", "track_id", "id")
# Faster than any pedestrian (or a jogger): such a step means the positions are not all in metres.
MAX_SPEED_MPS: Final = 10.0


@dataclass(frozen=True)
class Columns:
    """Which columns hold what; None picks the first of TIME_COLUMNS / AGENT_COLUMNS present."""

    time: str | None = None
    agent: str | None = None
    x: str = "x"
    y: str = "y"


def read_table(path: Path) -> pd.DataFrame:
    """The file as read: CSV (any delimiter pandas sniffs) or Parquet, chosen by extension."""
    if not path.is_file():
        raise RawDataError(path, "file not found")
    if path.stat().st_size == 0:
        raise RawDataError(path, "empty file: expected a table with a header line (time or frame, agent, x, y)")
    suffix = path.suffix.lower()
    try:
        if suffix in (".parquet", ".pq"):
            return pd.read_parquet(path)
        if suffix in (".csv", ".txt", ".tsv"):
            # utf-8-sig: a byte-order mark (Excel's "CSV UTF-8") is not part of the first column's name
            return pd.read_csv(path, sep=None, engine="python", dtype=str, skipinitialspace=True, encoding="utf-8-sig")
    except (ValueError, OSError, UnicodeDecodeError, pd.errors.ParserError, csv.Error) as exc:
        raise RawDataError(path, f"not a readable {suffix.lstrip('.')} table ({' '.join(str(exc).split())})") from exc
    raise RawDataError(path, f"unknown file type {suffix!r}: expected .csv or .parquet")


def _pick(path: Path, frame: pd.DataFrame, given: str | None, candidates: tuple[str, ...], what: str) -> str:
    if given is not None:
        if given not in frame.columns:
            raise RawDataError(path, f"no {what} column {given!r}; the file has columns {list(frame.columns)}")
        return given
    found = next((name for name in candidates if name in frame.columns), None)
    if found is None:
        raise RawDataError(
            path,
            f"no {what} column: expected one of {list(candidates)} (or name it with an option), "
            f"the file has columns {list(frame.columns)}",
        )
    return found


def _numbers(path: Path, frame: pd.DataFrame, column: str, csv: bool) -> np.ndarray:
    """A column as float64; the first non-numeric or non-finite cell is an error naming its line."""
    values = pd.to_numeric(frame[column], errors="coerce").to_numpy(dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        row = int(bad[0])
        where = f"line {row + 2}" if csv else f"row {row}"
        raise RawDataError(
            path, f"{where}, column {column!r}: expected a finite number, found {frame[column].iloc[row]!r}"
        )
    return values


def _agent_ids(path: Path, frame: pd.DataFrame, column: str, csv: bool) -> np.ndarray:
    """The agent column: whole numbers as int64 (so they sort as numbers), any other ids as text; an empty
    id is an error naming its line. Integer ids beyond int64 stay text, never wrapped or merged."""
    text = frame[column].astype("string").str.strip()
    if text.isna().any() or (text == "").any():
        row = int(np.flatnonzero((text.isna() | (text == "")).to_numpy())[0])
        raise RawDataError(path, f"{'line' if csv else 'row'} {row + 2 if csv else row}: empty agent id")
    whole = text.str.fullmatch(r"[+-]?\d+(\.0*)?").all()
    if whole:
        values = [int(t.split(".")[0]) for t in text]
        if all(-(2**63) <= v < 2**63 for v in values):
            return np.asarray(values, dtype=np.int64)
    return text.to_numpy(dtype=object).astype(str)


def read_goals(path: Path, columns: Columns = Columns(), units: str = "m") -> pd.DataFrame:
    """One goal per agent (agent, x, y in metres), from columns named as the tracks' are."""
    if units not in UNITS:
        raise RawDataError(path, f"unknown unit {units!r}: expected one of {', '.join(UNITS)}")
    frame = read_table(path)
    csv = path.suffix.lower() not in (".parquet", ".pq")
    agent = _agent_ids(path, frame, _pick(path, frame, columns.agent, AGENT_COLUMNS, "agent id"), csv)
    twice = np.flatnonzero(pd.Series(agent).duplicated().to_numpy())
    if twice.size:
        row = int(twice[0])
        raise RawDataError(
            path, f"{'line' if csv else 'row'} {row + 2 if csv else row}: agent {agent[row]} has a goal already; "
            "expected one goal per agent",
        )  # fmt: skip
    x = _numbers(path, frame, _pick(path, frame, columns.x, (), "x"), csv) * UNITS[units]
    y = _numbers(path, frame, _pick(path, frame, columns.y, (), "y"), csv) * UNITS[units]
    return pd.DataFrame({"agent": agent, "x": x, "y": y})


def read_tracks(
    path: Path,
    columns: Columns = Columns(),
    units: str = "m",
    seconds_per_unit: float | None = None,
    frame_step_s: float | None = None,
    max_speed_mps: float = MAX_SPEED_MPS,
    frames: bool | None = None,
) -> pd.DataFrame:
    """Rows (time_s, agent, x, y) sorted by agent then time; x, y in metres.

    seconds_per_unit: seconds per unit of the time column. Default: 1 for a time column (seconds); for a
    frame column, `frame_step_s` divided by the smallest gap between frame numbers (consecutive frames
    are one step of `frame_step_s` apart). An agent moving faster than `max_speed_mps` is an error: it
    usually means positions in another unit (see `units`). frames: whether the time column holds frame
    numbers; None judges by its name (FRAME_COLUMNS).
    """
    if units not in UNITS:
        raise RawDataError(path, f"unknown unit {units!r}: expected one of {', '.join(UNITS)}")
    frame = read_table(path)
    csv = path.suffix.lower() not in (".parquet", ".pq")
    time_col = _pick(path, frame, columns.time, TIME_COLUMNS, "time or frame")
    agent_col = _pick(path, frame, columns.agent, AGENT_COLUMNS, "agent id")
    x_col = _pick(path, frame, columns.x, (), "x")
    y_col = _pick(path, frame, columns.y, (), "y")
    if len(frame) == 0:
        raise RawDataError(path, "no rows: expected one row per agent and time")
    time = _numbers(path, frame, time_col, csv)
    if seconds_per_unit is None:
        if frames if frames is not None else time_col in FRAME_COLUMNS:
            gaps = np.diff(np.unique(time))
            if frame_step_s is None or gaps.size == 0:
                raise RawDataError(path, f"column {time_col!r} holds frame numbers: give the seconds per frame")
            seconds_per_unit = frame_step_s / float(gaps.min())
        else:
            seconds_per_unit = 1.0
    agent = _agent_ids(path, frame, agent_col, csv)
    scale = UNITS[units]
    tracks = pd.DataFrame(
        {
            "time_s": time * seconds_per_unit,
            "agent": agent,
            "x": _numbers(path, frame, x_col, csv) * scale,
            "y": _numbers(path, frame, y_col, csv) * scale,
            "line": np.arange(len(frame)) + (2 if csv else 0),
        }
    )
    tracks = tracks.sort_values(["agent", "time_s"], kind="stable").reset_index(drop=True)
    _check_rows(path, tracks, max_speed_mps, "line" if csv else "row")
    return tracks.drop(columns="line")


def _check_rows(path: Path, tracks: pd.DataFrame, max_speed_mps: float, where: str) -> None:
    """No agent twice at one time; no step faster than max_speed_mps (mixed or wrong units)."""
    same_agent = (tracks["agent"].to_numpy()[1:] == tracks["agent"].to_numpy()[:-1]).astype(bool)
    dt = np.diff(tracks["time_s"].to_numpy())
    twice = np.flatnonzero(same_agent & (dt <= 0))
    if twice.size:
        line, agent, time_s = _row(tracks, twice[0] + 1)
        raise RawDataError(path, f"{where} {line}: agent {agent} appears twice at time {time_s:.6g} s")
    step = np.hypot(np.diff(tracks["x"].to_numpy()), np.diff(tracks["y"].to_numpy()))
    speed = np.where(same_agent, step / np.where(dt > 0, dt, 1.0), 0.0)
    fast = np.flatnonzero(speed > max_speed_mps)
    if fast.size:
        line, agent, time_s = _row(tracks, fast[0] + 1)
        raise RawDataError(
            path,
            f"{where} {line}: agent {agent} moves {step[fast[0]]:.3g} m in {dt[fast[0]]:.3g} s "
            f"({speed[fast[0]]:.3g} m/s, above {max_speed_mps:g} m/s) at time {time_s:.6g} s: positions "
            "must all be in one unit (mixed units? set the unit of the file)",
        )


def _row(tracks: pd.DataFrame, i: int) -> tuple[int, object, float]:
    """(line, agent, time) of row i, each with its own type (a mixed row read whole turns ids into floats)."""
    return int(tracks["line"].iat[i]), tracks["agent"].iat[i], float(tracks["time_s"].iat[i])
