"""Slice tracks into 8 + 12 step windows for every leave-one-out benchmark part.

Reads: tracks. Writes: `windows/<fp>/windows.parquet` (one row per window) and `agent_windows.parquet`
(one row per valid agent-window with its 20 positions). Run: `fftool ingest` (builds both stages).

A window is `obs_len + pred_len` consecutive steps of one raw file; an agent-window is valid when the
pedestrian is present at every one of them. Everything is vectorised over rows: no Python loop over
pedestrians or steps.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fftool.artifacts.schema import AGENT_WINDOWS_FILE, TRACKS_FILE, WINDOWS_FILE, WINDOWS_SCHEMA, agent_windows_schema
from fftool.artifacts.store import Artifact
from fftool.config import PipelineConfig, WindowsConfig
from fftool.dataset.scenes import BENCHMARKS, LEAVE_ONE_OUT, PARTS
from fftool.errors import FftoolError
from fftool.stages.contract import Stage, StageContext

NAME: Final = "windows"
VERSION: Final = 1
INPUTS: Final = ("tracks",)


@dataclass(frozen=True)
class SequenceWindows:
    """The windows of one raw file (one source and split)."""

    first_step: np.ndarray  # (W,) first step of each window with >= 1 valid agent
    t0_step: np.ndarray  # (W,) last observed step
    t0_frame_id: np.ndarray  # (W,) raw frame id of the last observed step
    n_agents: np.ndarray  # (W,) valid agents per window
    n_present: np.ndarray  # (W,) pedestrians present at any step of the window
    agent_window: np.ndarray  # (M,) index into the W windows of each valid agent-window
    agent_ped: np.ndarray  # (M,) ped_id
    agent_xy: np.ndarray  # (M, L, 2) positions at the L window steps
    candidates: int  # window start steps considered (with or without valid agents)
    pedestrians: int
    frames: int


def slice_sequence(
    step: np.ndarray,
    ped_id: np.ndarray,
    frame_id: np.ndarray,
    xy: np.ndarray,
    window_len: int,
    obs_len: int,
    window_stride: int = 1,
) -> SequenceWindows:
    """Every valid agent-window of one raw file.

    Rows are runs of consecutive steps per pedestrian; a run of length n holds n - window_len + 1
    windows. Window starts are on the grid min_step + k * window_stride.
    """
    order = np.lexsort((step, ped_id))  # (N,) by pedestrian, then step
    s, p = step[order], ped_id[order]
    new_run = np.r_[True, (p[1:] != p[:-1]) | (s[1:] != s[:-1] + 1)]
    run_first_row = np.flatnonzero(new_run)  # (R,)
    run_len = np.diff(np.r_[run_first_row, len(s)])  # (R,)
    starts_per_run = np.maximum(run_len - window_len + 1, 0)
    run_of = np.repeat(np.arange(run_first_row.size), starts_per_run)  # (M0,)
    offset = np.arange(run_of.size) - np.repeat(np.cumsum(starts_per_run) - starts_per_run, starts_per_run)
    row0 = run_first_row[run_of] + offset  # (M0,) sorted-row index of each agent-window's first step
    min_step, max_step = int(step.min()), int(step.max())
    row0 = row0[(s[row0] - min_step) % window_stride == 0]

    first = s[row0]
    by_window = np.lexsort((p[row0], first))  # agent-windows ordered by window, then ped_id
    row0, first = row0[by_window], first[by_window]
    window_first, agent_window, n_agents = np.unique(first, return_inverse=True, return_counts=True)
    rows = order[row0[:, None] + np.arange(window_len)]  # (M, L) original row of each step

    n_steps = max_step - min_step + 1
    candidates = max(0, (n_steps - window_len) // window_stride + 1)
    return SequenceWindows(
        first_step=window_first,
        t0_step=window_first + obs_len - 1,
        t0_frame_id=frame_id[rows[np.searchsorted(first, window_first), obs_len - 1]]
        if rows.size
        else np.zeros(0, np.int64),
        n_agents=n_agents.astype(np.int32),
        n_present=_present_counts(step, ped_id, window_first, window_len),
        agent_window=agent_window.astype(np.int64),
        agent_ped=p[row0],
        agent_xy=xy[rows],
        candidates=candidates,
        pedestrians=int(np.unique(ped_id).size),
        frames=int(np.unique(step).size),
    )


def _present_counts(step: np.ndarray, ped_id: np.ndarray, window_first: np.ndarray, window_len: int) -> np.ndarray:
    """Pedestrians present at any step of each window, via a peds × distinct-steps presence prefix sum.

    Columns are the distinct steps seen, not every step of the span: a valid but far-off frame id
    (any int64 passes ingest) must not size the array by the gap.
    """
    steps, step_index = np.unique(step, return_inverse=True)
    _, ped_index = np.unique(ped_id, return_inverse=True)
    presence = np.zeros((ped_index.max() + 1, steps.size + 1), dtype=np.int32)  # (P, S+1)
    presence[ped_index, step_index + 1] = 1
    cumulative = presence.cumsum(axis=1)
    # Window w covers the distinct steps with index lo[w] <= i < hi[w].
    lo, hi = np.searchsorted(steps, window_first), np.searchsorted(steps, window_first + window_len)
    inside = cumulative[:, hi] - cumulative[:, lo]  # (P, W)
    return (inside > 0).sum(axis=0).astype(np.int32)


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

    summary = []
    # Stream one benchmark part at a time: the agent-window positions are the bulk of the data.
    with (
        pq.ParquetWriter(out_dir / WINDOWS_FILE, WINDOWS_SCHEMA) as window_writer,
        pq.ParquetWriter(out_dir / AGENT_WINDOWS_FILE, agent_windows_schema(window_len)) as agent_writer,
    ):
        for benchmark, part in ((b, p) for b in BENCHMARKS for p in PARTS):
            members = LEAVE_ONE_OUT[benchmark][part]
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
    return slice_all(cfg.windows, inputs["tracks"], ctx.out_dir)


STAGE = Stage(
    NAME,
    VERSION,
    INPUTS,
    command="fftool ingest",
    section=lambda cfg: cfg.windows,
    build=build,
    description=lambda cfg, benchmark: "windows",
)
