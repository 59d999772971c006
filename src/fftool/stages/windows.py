"""Slice tracks into 8 + 12 step windows for every leave-one-out benchmark part.

Reads: tracks. Writes: `windows/<fp>/windows.parquet` (one row per window) and `agent_windows.parquet`
(one row per valid agent-window with its 20 positions). Run: `fftool ingest` (builds both stages).

A window is `obs_len + pred_len` consecutive steps of one raw file; an agent-window is valid when the
pedestrian is present at every one of them. Everything is vectorised over rows: no Python loop over
pedestrians or steps.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fftool.artifacts.schema import (
    AGENT_WINDOWS_FILE,
    COMMANDS,
    TRACKS_FILE,
    VERSIONS,
    WINDOWS_FILE,
    WINDOWS_SCHEMA,
    agent_windows_schema,
)
from fftool.artifacts.store import Artifact
from fftool.config import PipelineConfig, WindowsConfig
from fftool.dataset.scenes import BENCHMARKS, LEAVE_ONE_OUT, PARTS
from fftool.dataset.windowing import SequenceWindows, slice_sequence
from fftool.errors import FftoolError
from fftool.stages.contract import Reads, Stage, StageContext

NAME: Final = "windows"


def slice_all(cfg: WindowsConfig, tracks: Artifact, out_dir: Any) -> dict[str, Any]:
    """Write windows.parquet and agent_windows.parquet for every benchmark part; return the summary.

    Args:
        cfg: the `windows` section of the configuration.
        tracks: the tracks artifact to slice.
        out_dir: the artifact's build folder.
    """
    window_len = cfg.obs_len + cfg.pred_len
    table = pq.read_table(tracks.file(TRACKS_FILE)).to_pandas()
    sequences: dict[tuple[str, str], SequenceWindows] = {}
    for (source, split), rows in table.groupby(["source", "split"], observed=True, sort=False):
        sequences[(str(source), str(split))] = slice_sequence(
            rows["step"].to_numpy(),
            rows["ped_id"].to_numpy(),
            rows["frame_id"].to_numpy(),
            rows[["x", "y"]].to_numpy(),
            window_len,
            cfg.obs_len,
            cfg.window_stride,
        )

    split = _split_of(tracks)
    summary = []
    # Stream one benchmark part at a time: the agent-window positions are the bulk of the data.
    with (
        pq.ParquetWriter(out_dir / WINDOWS_FILE, WINDOWS_SCHEMA) as window_writer,
        pq.ParquetWriter(out_dir / AGENT_WINDOWS_FILE, agent_windows_schema(window_len)) as agent_writer,
    ):
        for benchmark, part in ((b, p) for b in split for p in PARTS):
            members = split[benchmark][part]
            windows, agents = _assemble(benchmark, part, members, sequences)
            window_writer.write_table(windows)
            agent_writer.write_table(agents)
            summary.append(
                {
                    "benchmark": benchmark,
                    "part": part,
                    "sources": [f"{source}:{split}" for source, split in members],
                    "candidate_windows": sum(sequences[m].candidates for m in members),
                    "windows": windows.num_rows,
                    "agent_windows": agents.num_rows,
                    "pedestrians": sum(sequences[m].pedestrians for m in members),
                    "frames": sum(sequences[m].frames for m in members),
                }
            )
    if not any(row["agent_windows"] for row in summary):
        raise FftoolError(
            f"windows of obs_len + pred_len = {window_len} steps: no pedestrian of any recording is present for "
            f"{window_len} consecutive steps, so there is nothing to train or evaluate on; lower "
            "windows.obs_len / windows.pred_len"
        )
    return {"window_len": window_len, "obs_len": cfg.obs_len, "pred_len": cfg.pred_len, "summary": summary}


def _split_of(tracks: Artifact) -> dict[str, dict[str, tuple[tuple[str, str], ...]]]:
    """benchmark -> part -> (source, split) files: ETH/UCY's leave-one-out table, or a dataset's own parts
    (recorded by the tracks stage), so the split follows the tracks' fingerprint."""
    dataset = tracks.manifest.stats.get("dataset")
    if dataset is None:
        return {benchmark: LEAVE_ONE_OUT[benchmark] for benchmark in BENCHMARKS}
    parts = {part: tuple((source, split) for source, split in dataset["parts"][part]) for part in PARTS}
    return {dataset["name"]: parts}


def _constant(value: str, n: int) -> pa.DictionaryArray:
    """A dictionary column holding one string n times."""
    return pa.DictionaryArray.from_arrays(pa.array(np.zeros(n, np.int8)), pa.array([value]))


def _labels(values: list[str], counts: np.ndarray) -> pa.DictionaryArray:
    """A dictionary column holding values[i] counts[i] times, in order."""
    distinct, index = np.unique(values, return_inverse=True)
    return pa.DictionaryArray.from_arrays(pa.array(np.repeat(index.astype(np.int8), counts)), pa.array(distinct))


def _assemble(
    benchmark: str,
    part: str,
    members: tuple[tuple[str, str], ...],
    sequences: dict[tuple[str, str], SequenceWindows],
) -> tuple[pa.Table, pa.Table]:
    """Concatenate the member files' windows into one benchmark part with window ids 0..W-1."""
    seqs = [sequences[m] for m in members]
    sizes = np.array([seq.first_step.size for seq in seqs])
    offsets = np.r_[0, np.cumsum(sizes)[:-1]]
    n_windows, n_agents = int(sizes.sum()), sum(seq.agent_ped.size for seq in seqs)
    window_len = seqs[0].agent_xy.shape[1]
    first_step = np.concatenate([seq.first_step for seq in seqs])
    windows = pa.Table.from_arrays(
        [
            _constant(benchmark, n_windows),
            _constant(part, n_windows),
            pa.array(np.arange(n_windows), pa.int64()),
            _labels([source for source, _ in members], sizes),
            _labels([split for _, split in members], sizes),
            pa.array(first_step, pa.int64()),
            pa.array(np.concatenate([seq.t0_step for seq in seqs]), pa.int64()),
            pa.array(np.concatenate([seq.t0_frame_id for seq in seqs]), pa.int64()),
            pa.array(np.concatenate([seq.n_agents for seq in seqs]), pa.int32()),
            pa.array(np.concatenate([seq.n_present for seq in seqs]), pa.int32()),
        ],
        schema=WINDOWS_SCHEMA,
    )
    xy = np.concatenate([seq.agent_xy.reshape(-1) for seq in seqs])
    agents = pa.Table.from_arrays(
        [
            _constant(benchmark, n_agents),
            _constant(part, n_agents),
            pa.array(np.concatenate([seq.agent_window + off for seq, off in zip(seqs, offsets)]), pa.int64()),
            pa.array(np.concatenate([seq.agent_ped for seq in seqs]), pa.int64()),
            pa.FixedSizeListArray.from_arrays(pa.array(xy, pa.float64()), 2 * window_len),
        ],
        schema=agent_windows_schema(window_len),
    )
    return windows, agents


def build(cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: StageContext) -> dict[str, Any]:
    """The stage contract: every benchmark part's windows and agent-windows from the tracks."""
    return slice_all(cfg.windows, inputs["tracks"], ctx.dir)


STAGE = Stage(
    NAME,
    VERSIONS[NAME],
    COMMANDS[NAME],
    label="windows",
    declare=lambda cfg: Reads(params=("windows.*",), artifacts={"tracks": None}),
    build=build,
    section="windows",
)
