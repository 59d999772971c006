"""A user's own trajectory dataset, described by a small TOML, as one more benchmark beside ETH/UCY.

The TOML names the benchmark, the files of its train/val/test parts (paths relative to the TOML), their
columns, units and time step, and optionally a scene image with its homography (docs/data.md, "Your own
dataset"). Files are read by `trackfiles.read_tracks` (the reader `fftool predict` uses) and put on the
model's time grid by `steps.to_steps`, so both commands accept the same files with the same errors.

Each file becomes one source of the tracks artifact, named `<name>/<path relative to the TOML>`, with its
part as split (train | val | test); `scenes.scene_of` maps such a source to the dataset's scene (its name).
"""

from __future__ import annotations

import functools
import hashlib
import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Final, Literal

import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from fftool.dataset.scenes import BENCHMARKS, PARTS
from fftool.dataset.steps import RESAMPLING_VERSION, to_steps
from fftool.dataset.trackfiles import Columns, read_tracks
from fftool.errors import RawDataError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on 3.10 only
    import tomli as tomllib

NAME_PATTERN: Final = r"^[a-z][a-z0-9_-]*$"  # lower case, no comma, no '/' (sources are <name>/<file>)
RESERVED: Final = (*BENCHMARKS, "all")


class _Strict(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


class DatasetColumns(_Strict):
    """Which column holds what. One of `time` (seconds) or `frame` (frame numbers); neither: found by name."""

    time: str | None = None
    frame: str | None = None
    agent: str | None = None
    x: str = "x"
    y: str = "y"

    @model_validator(mode="after")
    def _one_clock(self) -> DatasetColumns:
        if self.time is not None and self.frame is not None:
            raise ValueError("give `time` (seconds) or `frame` (frame numbers), not both")
        return self


class DatasetFiles(_Strict):
    train: list[str] = Field(min_length=1)
    val: list[str] = Field(min_length=1)
    test: list[str] = Field(min_length=1)


class DatasetSpec(_Strict):
    """The dataset TOML, validated."""

    name: str = Field(pattern=NAME_PATTERN)
    time_step_s: float = Field(gt=0)  # seconds between consecutive samples of the files (one frame)
    units: Literal["m", "cm", "mm"] = "m"
    columns: DatasetColumns = DatasetColumns()
    files: DatasetFiles
    # An agent missing for longer than this is an error (give a re-appearing agent a new id); shorter gaps
    # are filled by linear interpolation. Default: 2 × time_step_s (one missing sample).
    max_gap_s: float | None = Field(None, gt=0)
    scene_image: str | None = None
    homography: str | None = None  # 3×3 text matrix, image pixel -> world metres (like ETH's H.txt)
    # Two files of the same bytes (one file named twice, by another spelling, a link or a copy) are refused:
    # across parts test numbers would measure training data, within one its rows would count twice. Set true
    # to accept it knowingly (not part of any fingerprint: it changes no data).
    allow_shared_files: bool = False

    @field_validator("name")
    @classmethod
    def _not_eth_ucy(cls, name: str) -> str:
        if name in RESERVED:
            raise ValueError(f"{name!r} is an ETH/UCY benchmark name; choose another")
        return name

    @model_validator(mode="after")
    def _image_with_homography(self) -> DatasetSpec:
        if (self.scene_image is None) != (self.homography is None):
            raise ValueError("scene_image and homography go together: give both or neither")
        return self


@dataclass(frozen=True)
class Dataset:
    """A validated dataset TOML and the folder its paths are relative to."""

    spec: DatasetSpec
    path: Path  # the TOML

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def root(self) -> Path:
        return self.path.parent

    def files(self) -> list[tuple[str, str, Path]]:
        """(part, source, path) of every file, in part order then as listed."""
        return [
            (part, f"{self.name}/{rel}", self.root / rel) for part in PARTS for rel in getattr(self.spec.files, part)
        ]

    def scene_files(self) -> tuple[Path, Path] | None:
        """(image, homography) paths, or None for a dataset without a scene image."""
        if self.spec.scene_image is None or self.spec.homography is None:
            return None
        return self.root / self.spec.scene_image, self.root / self.spec.homography

    def parts(self) -> dict[str, list[list[str]]]:
        """part -> [[source, split], ...]: the leave-one-out table's row for this one benchmark."""
        return {part: [[source, part] for p, source, _ in self.files() if p == part] for part in PARTS}

    def input_hashes(self) -> dict[str, str]:
        """What the tracks fingerprint hashes: the description (not its paths' spelling) and each file's bytes."""
        described = self.spec.model_dump(mode="json", exclude={"scene_image", "homography", "allow_shared_files"})
        hashes = {"dataset": hashlib.sha256(json.dumps(described, sort_keys=True).encode()).hexdigest()}
        hashes["resampling"] = str(RESAMPLING_VERSION)  # how to_steps puts the files on the grid
        seen: dict[str, tuple[str, str]] = {}
        for part, source, path in self.files():
            if not path.is_file():
                raise RawDataError(path, f"file not found (files.{part} of {self.path})")
            digest = hashes[f"dataset/{part}/{source}"] = _sha256(path)
            if digest in seen and not self.spec.allow_shared_files:
                first_part, first = seen[digest]
                harm = (
                    "test numbers would measure training data" if first_part != part else "its rows would count twice"
                )
                raise RawDataError(
                    self.path,
                    f"files.{first_part} {first!r} and files.{part} {source.split('/', 1)[1]!r} hold the same bytes: "
                    f"{harm}; give each part its own files, or set allow_shared_files = true to accept it",
                )
            seen.setdefault(digest, (part, source.split("/", 1)[1]))
        return hashes

    def scene_hashes(self) -> dict[str, str]:
        """The scene image's and homography's bytes (empty without a scene image), for the maps fingerprint."""
        found = self.scene_files()
        if found is None:
            return {f"scenes/{self.name}": "no scene image"}
        for what, path in zip(("scene_image", "homography"), found):
            if not path.is_file():
                raise RawDataError(path, f"file not found ({what} of {self.path})")
        return {f"scenes/{self.name}/{what}": _sha256(path) for what, path in zip(("image", "homography"), found)}


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def load_dataset(path: Path | str) -> Dataset:
    """The dataset TOML at `path`, validated; every problem is one line naming the file and the field."""
    path = Path(path)
    try:
        stat = path.stat()
    except OSError:
        raise RawDataError(path, "dataset file not found (data.dataset)") from None
    return _load(path.resolve(), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=16)
def _load(path: Path, mtime_ns: int, size: int) -> Dataset:  # the stat keys the cache: an edit is re-read
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise RawDataError(path, f"not a valid TOML file ({' '.join(str(exc).split())})") from exc
    try:
        return Dataset(DatasetSpec.model_validate(raw), path)
    except ValidationError as exc:
        issue = exc.errors()[0]
        field = ".".join(str(p) for p in issue["loc"])  # empty: a check across fields, which names them
        if issue["type"] == "missing":
            problem = "missing"
        elif issue["type"] == "extra_forbidden":
            problem = "unknown field"
        else:
            given = issue.get("input")
            got = "" if isinstance(given, (dict, list)) else f" (got {given!r})"
            problem = f"{issue['msg'].removeprefix('Value error, ')}{got}"
        more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
        raise RawDataError(path, f"{field + ': ' if field else ''}{problem}{more}") from exc


def valid_name(name: str) -> bool:
    return re.fullmatch(NAME_PATTERN, name) is not None


@dataclass(frozen=True)
class FileTracks:
    """One file on the model's grid: rows sorted by step then agent, steps from 0."""

    part: str
    source: str
    step: np.ndarray  # (N,) int64
    ped_id: np.ndarray  # (N,) int64
    xy: np.ndarray  # (N, 2) float64 metres
    first_time_s: float
    warnings: list[str]


def read_file(dataset: Dataset, part: str, source: str, path: Path, dt_s: float) -> FileTracks:
    """One file of the dataset, in metres, on the grid of `dt_s` seconds (resampled when its step differs)."""
    spec = dataset.spec
    cols = spec.columns
    clock = cols.frame if cols.frame is not None else cols.time
    rows = read_tracks(
        path,
        Columns(clock, cols.agent, cols.x, cols.y),
        spec.units,
        frame_step_s=spec.time_step_s,
        frames=True if cols.frame is not None else (False if cols.time is not None else None),
    )
    max_gap = spec.max_gap_s if spec.max_gap_s is not None else 2 * spec.time_step_s
    on_grid = to_steps(path, rows, dt_s, max_gap)
    labels = on_grid.labels
    # Numeric ids are kept; other ids become their rank in sorted order.
    ped = labels[on_grid.agent].astype(np.int64) if labels.dtype.kind in "iu" else on_grid.agent
    step = on_grid.step - on_grid.step.min()
    order = np.lexsort((ped, step))
    first_time = on_grid.last_time_s + on_grid.step.min() * dt_s
    return FileTracks(part, source, step[order], ped[order], on_grid.xy[order], first_time, on_grid.warnings)


def tracks_frame(files: list[FileTracks]) -> pd.DataFrame:
    """The files as tracks rows (source, split, frame_id = step, step, ped_id, x, y)."""
    return pd.DataFrame(
        {
            "source": np.concatenate([np.full(f.step.size, f.source, dtype=object) for f in files]),
            "split": np.concatenate([np.full(f.step.size, f.part, dtype=object) for f in files]),
            "frame_id": np.concatenate([f.step for f in files]),
            "step": np.concatenate([f.step for f in files]),
            "ped_id": np.concatenate([f.ped_id for f in files]),
            "x": np.concatenate([f.xy[:, 0] for f in files]),
            "y": np.concatenate([f.xy[:, 1] for f in files]),
        }
    )


def write_dataset(
    out_dir: Path, name: str, time_s: np.ndarray, agent: np.ndarray, xy: np.ndarray, time_step_s: float
) -> Path:
    """Rows (time_s, agent, x, y in metres) as a dataset: split in time 60/20/20 into train.csv, val.csv and
    test.csv (as ETH/UCY's train/val files are), plus dataset.toml describing them. Returns the TOML's path."""
    if not valid_name(name) or name in RESERVED:
        raise RawDataError(
            out_dir, f"dataset name {name!r}: expected lower-case letters, digits, - or _, not ETH/UCY's"
        )
    out_dir.mkdir(parents=True, exist_ok=True)
    end = float(time_s.max()) if time_s.size else 0.0
    cuts = {"train": (-np.inf, 0.6 * end), "val": (0.6 * end, 0.8 * end), "test": (0.8 * end, np.inf)}
    for part, (low, high) in cuts.items():
        keep = (time_s >= low) & (time_s < high)
        frame = pd.DataFrame({"time": time_s[keep], "agent_id": agent[keep], "x": xy[keep, 0], "y": xy[keep, 1]})
        frame.to_csv(out_dir / f"{part}.csv", index=False, float_format="%.4f")
    toml = out_dir / "dataset.toml"
    toml.write_text(
        f'name = "{name}"\n'
        f"time_step_s = {time_step_s:g}\n"
        'units = "m"\n\n'
        "[columns]\n"
        'time = "time"\n'
        'agent = "agent_id"\n'
        'x = "x"\n'
        'y = "y"\n\n'
        "[files]\n"
        'train = ["train.csv"]\n'
        'val = ["val.csv"]\n'
        'test = ["test.csv"]\n'
    )
    return toml
