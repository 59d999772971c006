"""Validate every raw ETH/UCY file, or a dataset TOML's files, and store them as one Parquet table.

Reads: the raw Social-GAN text files (8 sources × all/train/val), or with `data.dataset` the files the
dataset TOML lists (fftool.dataset.custom). Writes: `tracks/<fp>/tracks.parquet`.
Run: `fftool ingest --raw ../shared/data/eth_ucy/raw`, or `fftool ingest --dataset my/dataset.toml`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Final

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fftool.artifacts.hashing import sha256_file
from fftool.artifacts.schema import COMMANDS, TRACKS_FILE, TRACKS_SCHEMA, VERSIONS
from fftool.artifacts.store import Artifact
from fftool.config import IngestConfig, PipelineConfig
from fftool.dataset.custom import Dataset, load_dataset, read_file, tracks_frame
from fftool.dataset.rawfiles import RawTable, read_raw
from fftool.dataset.scenes import SOURCES, SPLITS, raw_relpath
from fftool.errors import RawDataError
from fftool.stages.contract import Reads, Stage, StageContext

NAME: Final = "tracks"


def raw_files(raw_dir: Path) -> dict[tuple[str, str], Path]:
    """The 24 expected raw files by (source, split); one error listing every missing one."""
    if not raw_dir.is_dir():
        raise RawDataError(raw_dir, "raw data directory not found (run `fftool fetch-data` to download it)")
    expected = {(source, split): raw_dir / raw_relpath(source, split) for source in SOURCES for split in SPLITS}
    missing = sorted(raw_relpath(*key) for key, path in expected.items() if not path.is_file())
    if missing:
        shown = ", ".join(missing[:6]) + (f" and {len(missing) - 6} more" if len(missing) > 6 else "")
        raise RawDataError(
            raw_dir,
            f"missing {len(missing)} of {len(expected)} expected Social-GAN files: {shown} "
            "(expected all_data/<source>.txt, train/<source>_train.txt, val/<source>_val.txt)",
        )
    return expected


def raw_input_hashes(raw_dir: Path) -> dict[str, str]:
    """Content hashes of the raw files: the tracks fingerprint depends on bytes, not on paths."""
    return {f"raw/{raw_relpath(*key)}": sha256_file(path) for key, path in raw_files(raw_dir).items()}


def _check_train_val(tables: Mapping[tuple[str, str], RawTable]) -> list[str]:
    """train + val should equal all, row for row; a mismatch is recorded as a warning."""
    warnings = []
    for source in SOURCES:
        whole, train, val = (tables[(source, split)] for split in SPLITS)
        if len(train) + len(val) != len(whole):
            warnings.append(f"{source}: train ({len(train)} rows) + val ({len(val)} rows) != all ({len(whole)} rows)")
        elif train.frame_id.max() >= val.frame_id.min():
            warnings.append(f"{source}: train and val overlap in time")
    return warnings


def ingest_raw(
    cfg: IngestConfig,
    raw_dir: Path,
    out_dir: Path,
    on_file: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Parse and validate every raw file, write tracks.parquet, return the manifest stats.

    Args:
        cfg: the `ingest` section of the configuration.
        raw_dir: folder holding all_data/, train/ and val/.
        out_dir: the artifact's build folder.
        on_file: called with each file's relative path after it is read (progress).
    """
    tables: dict[tuple[str, str], RawTable] = {}
    for (source, split), path in raw_files(raw_dir).items():
        tables[(source, split)] = read_raw(path, cfg.frame_stride, cfg.duplicates)
        if on_file:
            on_file(raw_relpath(source, split))

    columns: dict[str, list[np.ndarray]] = {name: [] for name in TRACKS_SCHEMA.names}
    files = {}
    for (source, split), table in tables.items():
        order = np.lexsort((table.ped_id, table.frame_id))
        n = len(table)
        columns["source"].append(np.full(n, source, dtype=object))
        columns["split"].append(np.full(n, split, dtype=object))
        columns["frame_id"].append(table.frame_id[order])
        columns["step"].append(table.frame_id[order] // cfg.frame_stride)
        columns["ped_id"].append(table.ped_id[order])
        columns["x"].append(table.x[order])
        columns["y"].append(table.y[order])
        steps = np.unique(table.frame_id)
        files[raw_relpath(source, split)] = {
            "rows": n,
            "pedestrians": int(np.unique(table.ped_id).size),
            "frames": int(steps.size),
            "first_frame_id": int(steps[0]),
            "last_frame_id": int(steps[-1]),
            # The smallest gap between consecutive frames actually seen: the data's own stride. The ids
            # are sorted and distinct, so uint64 differences are exact even across the whole int64 range.
            "observed_stride": int(np.diff(steps.view(np.uint64)).min()) if steps.size > 1 else None,
        }
    arrays = [
        pa.array(np.concatenate(columns[name])).dictionary_encode().cast(fld.type)
        if pa.types.is_dictionary(fld.type)
        else pa.array(np.concatenate(columns[name]), type=fld.type)
        for name, fld in zip(TRACKS_SCHEMA.names, TRACKS_SCHEMA)
    ]
    pq.write_table(pa.Table.from_arrays(arrays, schema=TRACKS_SCHEMA), out_dir / TRACKS_FILE)

    warnings = [w for table in tables.values() for w in table.warnings] + _check_train_val(tables)
    return {
        "rows": int(sum(len(t) for t in tables.values())),
        "frame_stride": cfg.frame_stride,
        "dt_s": cfg.dt_s,
        "files": files,
        "warnings": warnings,
    }


def ingest_dataset(
    cfg: IngestConfig, dataset: Dataset, out_dir: Path, on_file: Callable[[str], None] | None = None
) -> dict[str, Any]:
    """Read a dataset's files onto the model's grid of `ingest.dt_s` seconds, write tracks.parquet.

    Each file is one source (`<name>/<file>`) whose split is its part; `frame_id` is the grid step (from 0).
    The stats carry the dataset's parts, which the windows stage uses as this benchmark's split.
    """
    read = []
    for part, source, path in dataset.files():
        read.append(read_file(dataset, part, source, path, cfg.dt_s))
        if on_file:
            on_file(source)
    frame = tracks_frame(read)
    arrays = [
        pa.array(frame[name].to_numpy()).dictionary_encode().cast(fld.type)
        if pa.types.is_dictionary(fld.type)
        else pa.array(frame[name].to_numpy(), type=fld.type)
        for name, fld in zip(TRACKS_SCHEMA.names, TRACKS_SCHEMA)
    ]
    pq.write_table(pa.Table.from_arrays(arrays, schema=TRACKS_SCHEMA), out_dir / TRACKS_FILE)
    files = {
        f.source: {
            "part": f.part,
            "rows": int(f.step.size),
            "pedestrians": int(np.unique(f.ped_id).size),
            "frames": int(np.unique(f.step).size),
            "first_time_s": f.first_time_s,
        }
        for f in read
    }
    return {
        "rows": len(frame),
        "dt_s": cfg.dt_s,
        "dataset": {
            "name": dataset.name,
            "file_time_step_s": dataset.spec.time_step_s,
            "units": dataset.spec.units,
            "parts": dataset.parts(),
        },
        "files": files,
        "warnings": [w for f in read for w in f.warnings],
    }


def build(cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: StageContext) -> dict[str, Any]:
    """The stage contract: validate the raw files of `data.raw_dir` (or `data.dataset`'s) into `tracks.parquet`."""
    if cfg.data.dataset:
        dataset = load_dataset(cfg.data.dataset)
        total, count = len(dataset.files()), iter(range(1, len(dataset.files()) + 1))
        return ingest_dataset(
            cfg.ingest, dataset, ctx.dir, on_file=lambda name: ctx.on_progress(name, next(count), total)
        )
    files = len(SOURCES) * len(SPLITS)
    done = iter(range(1, files + 1))
    return ingest_raw(
        cfg.ingest, Path(cfg.data.raw_dir), ctx.dir, on_file=lambda name: ctx.on_progress(name, next(done), files)
    )


def declare(cfg: PipelineConfig) -> Reads:
    """The ingest settings and the raw files by content (a dataset TOML's description and files, or ETH/UCY's)."""
    data = cfg.data

    def raw() -> dict[str, str]:
        return load_dataset(data.dataset).input_hashes() if data.dataset else raw_input_hashes(Path(data.raw_dir))

    return Reads(params=("ingest.*",), raw_files=raw, locations=("data.raw_dir", "data.dataset"))


STAGE = Stage(
    NAME,
    VERSIONS[NAME],
    COMMANDS[NAME],
    label="ingest raw files",
    declare=declare,
    build=build,
    section="ingest",
)
