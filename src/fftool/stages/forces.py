"""Social-force features for every valid agent-window of every benchmark part.

Reads: tracks (all positions, for DBSCAN groups and neighbours) and windows. Writes:
`forces/<fp>/` with index.parquet and memory-mappable .npy arrays (see schema.FORCES_ARRAYS).
Run: `fftool forces`. The math lives in `fftool.science.social_forces`; this module only orchestrates.

A window's features depend only on its own 20 steps, so each distinct window (source, split, start)
is computed once and shared by every benchmark part that contains it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import torch

from fftool.artifacts.schema import (
    AGENT_WINDOWS_FILE,
    COMMANDS,
    FORCES_ARRAYS,
    FORCES_INDEX_FILE,
    TRACKS_FILE,
    VERSIONS,
    WINDOWS_FILE,
)
from fftool.artifacts.store import Artifact
from fftool.config import ForcesConfig, PipelineConfig
from fftool.errors import FftoolError
from fftool.learning.batches import pair_budget_batches
from fftool.science.groups import cluster_frames
from fftool.science.social_forces import group_ids, window_forces
from fftool.stages.contract import Reads, Stage, StageContext

NAME: Final = "forces"
# The force constants (ForcesConfig fields) each array depends on, so a consumer that reads some arrays
# is fingerprinted on these alone (`view`): F_dr does not change with the field of view, F_re does not
# change with tau. tests/test_fingerprints.py checks every entry by perturbing each constant.
_DESIRED_SPEED = frozenset({"desired_speed", "desired_speed_mps"})
_GROUPS = frozenset({"dbscan_eps_m", "dbscan_min_samples", "group_min_steps", "neighbours"})
ARRAY_PARAMS: Final[dict[str, frozenset[str]]] = {
    "velocity": frozenset(),
    "goal": frozenset(),
    "speed0": _DESIRED_SPEED,
    "f_dr": _DESIRED_SPEED | {"tau_s", "goal_min_distance_m"},
    "group_id": _GROUPS,  # ids are window-local slots, and `neighbours` decides the slots
    "f_re": _GROUPS
    | {"goal_min_distance_m", "v0_m2_s2", "sigma_m", "ellipse_step_s", "fov_deg", "fov_out_of_view", "fov_reading"},
}
# Pairwise work per batch (windows × actors² × steps): bounds the pairwise tensors to ~8 MB each.
_PAIR_BUDGET = 1_000_000
# One recording's dense (pedestrian, step) grid: 25 bytes a cell, so about 1.2 GB at most. The real
# recordings need at most about 0.6 million cells; a frame-id jump of millions would need terabytes.
MAX_GRID_CELLS = 50_000_000


@dataclass
class Sequence:
    """One raw file as dense (pedestrian × step) arrays."""

    first_step: int
    position: np.ndarray  # (P, S, 2)
    present: np.ndarray  # (P, S) bool
    label: np.ndarray  # (P, S) DBSCAN label, -1 noise or absent
    ped_id: np.ndarray  # (P,) sorted


def _sequences(tracks: pd.DataFrame, cfg: ForcesConfig) -> dict[tuple[str, str], Sequence]:
    frame_key = tracks.groupby(["source", "split", "step"], observed=True, sort=False).ngroup().to_numpy()
    labels = cluster_frames(frame_key, tracks[["x", "y"]].to_numpy(), cfg.dbscan_eps_m, cfg.dbscan_min_samples)
    tracks = tracks.assign(label=labels)
    sequences = {}
    for (source, split), rows in tracks.groupby(["source", "split"], observed=True, sort=False):
        ped_id, ped = np.unique(rows["ped_id"].to_numpy(), return_inverse=True)
        step = rows["step"].to_numpy()
        first, n_steps = int(step.min()), int(step.max() - step.min() + 1)
        if ped_id.size * n_steps > MAX_GRID_CELLS:
            raise FftoolError(
                f"{source} ({split}): {ped_id.size} pedestrians over {n_steps} steps (frame ids {first} to "
                f"{int(step.max())}) exceed the dense time grid forces are computed on "
                f"({MAX_GRID_CELLS:,} pedestrian-steps); split the recording where its frame ids jump"
            )
        position = np.zeros((ped_id.size, n_steps, 2))
        present = np.zeros((ped_id.size, n_steps), dtype=bool)
        label = np.full((ped_id.size, n_steps), -1, dtype=np.int64)
        position[ped, step - first] = rows[["x", "y"]].to_numpy()
        present[ped, step - first] = True
        label[ped, step - first] = rows["label"].to_numpy()
        sequences[(str(source), str(split))] = Sequence(first, position, present, label, ped_id)
    return sequences


@dataclass
class _Features:
    """Per distinct agent-window results of one sequence, keyed by (first_step, ped_id)."""

    first_step: np.ndarray
    ped_id: np.ndarray
    arrays: dict[str, np.ndarray]
    pairs: int
    grouped_pairs: int


def _compute_sequence(
    seq: Sequence,
    starts: np.ndarray,
    cfg: ForcesConfig,
    *,
    dt_s: float,
    obs_len: int,
    window_len: int,
    device: torch.device,
) -> _Features:
    """Forces for the windows starting at `starts` (absolute steps) of one sequence, in padded batches."""
    steps = (starts - seq.first_step)[:, None] + np.arange(window_len)  # (W, L) local step indices
    window_present = seq.present[:, steps].transpose(1, 0, 2)  # (W, P, L)
    valid = window_present.all(axis=-1)  # (W, P)
    actors = window_present.any(axis=-1) if cfg.neighbours == "present" else valid
    n_actors = actors.sum(axis=1)
    order = np.argsort(n_actors, kind="stable")
    outputs: dict[str, list[np.ndarray]] = {name: [] for name in FORCES_ARRAYS}
    keys_first, keys_ped = [], []
    pairs = grouped = 0
    for run in pair_budget_batches(n_actors[order], _PAIR_BUDGET // window_len):  # pairs × steps in budget
        chunk = order[run]
        slot_ped, slot_mask = _slots(actors[chunk])  # (B, N) pedestrian index per slot
        chunk_steps = steps[chunk]  # (B, L)
        ped_index = np.where(slot_mask, slot_ped, 0)
        position = seq.position[ped_index[:, :, None], chunk_steps[:, None, :]]  # (B, N, L, 2)
        present = seq.present[ped_index[:, :, None], chunk_steps[:, None, :]] & slot_mask[:, :, None]
        label = np.where(present[:, :, :obs_len], seq.label[ped_index[:, :, None], chunk_steps[:, None, :obs_len]], -1)
        is_valid = valid[chunk[:, None], ped_index] & slot_mask  # (B, N)
        # Forces are translation-invariant, so centring each window on its first valid agent's last observed
        # position keeps float32 precise to ~1e-6 m (a valid agent: the same origin whoever else is present).
        first_valid = is_valid.argmax(axis=1)
        origin = position[np.arange(len(chunk)), first_valid, obs_len - 1][:, None, None]  # (B, 1, 1, 2)
        tensors = {
            "position": torch.as_tensor(position - origin, dtype=torch.float32, device=device),
            "present": torch.as_tensor(present, device=device),
            "label": torch.as_tensor(label, device=device),
        }
        result = window_forces(
            tensors["position"],
            tensors["present"],
            tensors["position"][:, :, -1],  # the goal: ground truth at the last window step
            tensors["label"],
            cfg,
            dt_s=dt_s,
            obs_len=obs_len,
            heading=torch.as_tensor(~is_valid & slot_mask, device=device),
        )
        groups = result.groups & torch.as_tensor(is_valid[:, :, None] & is_valid[:, None, :], device=device)
        gid = group_ids(groups).cpu().numpy()
        pairs += int((is_valid.sum(1) * (is_valid.sum(1) - 1)).sum())
        grouped += int(groups.sum())
        keep = is_valid
        outputs["f_dr"].append(result.f_dr.cpu().numpy()[keep])
        outputs["f_re"].append(result.f_re.cpu().numpy()[keep])
        outputs["velocity"].append(result.velocity.cpu().numpy()[keep])
        outputs["goal"].append(position[:, :, -1][keep])
        outputs["speed0"].append(result.speed0.cpu().numpy()[keep])
        outputs["group_id"].append(gid[keep])
        keys_first.append(np.broadcast_to(starts[chunk][:, None], keep.shape)[keep])
        keys_ped.append(seq.ped_id[ped_index][keep])
    dtypes = {"group_id": np.int32}
    arrays = {name: np.concatenate(parts).astype(dtypes.get(name, np.float32)) for name, parts in outputs.items()}
    return _Features(np.concatenate(keys_first), np.concatenate(keys_ped), arrays, pairs, grouped)


def _slots(actors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(B, P) bool -> (B, N) pedestrian indices in ascending order per row, and the slot mask."""
    n = max(int(actors.sum(axis=1).max()), 1)
    rank = np.cumsum(actors, axis=1) - 1  # slot of each actor
    slot_ped = np.zeros((actors.shape[0], n), dtype=np.int64)
    rows, peds = np.nonzero(actors)
    slot_ped[rows, rank[rows, peds]] = peds
    mask = np.arange(n) < actors.sum(axis=1)[:, None]
    return slot_ped, mask


def _scatter(
    results: dict[tuple[str, str], _Features], window_table: pd.DataFrame, agents: pd.DataFrame
) -> tuple[pd.DataFrame, dict[str, np.ndarray]]:
    """The per-recording results in the row order of agent_windows.parquet (a recording serves many parts)."""
    keys = pd.concat(
        [
            pd.DataFrame({"source": s, "split": p, "first_step": r.first_step, "ped_id": r.ped_id})
            for (s, p), r in results.items()
        ],
        ignore_index=True,
    )
    keys["feature_row"] = np.arange(len(keys))
    rows = agents.merge(window_table, on=["benchmark", "part", "window_id"], how="left", sort=False)
    rows["source"], rows["split"] = rows["source"].astype(str), rows["split"].astype(str)
    rows = rows.merge(keys, on=["source", "split", "first_step", "ped_id"], how="left", sort=False)
    assert rows["feature_row"].notna().all(), "every valid agent-window must have features"
    take = rows["feature_row"].to_numpy(dtype=np.int64)
    return rows, {name: np.concatenate([r.arrays[name] for r in results.values()])[take] for name in FORCES_ARRAYS}


def compute(
    cfg: ForcesConfig,
    tracks: Artifact,
    windows: Artifact,
    out_dir: Path,
    device: torch.device | None = None,
    on_sequence: Callable[[str, int], None] | None = None,
) -> dict[str, Any]:
    """Compute the features of every valid agent-window; write index.parquet and the .npy arrays.

    Args:
        cfg: the `forces` section of the configuration.
        tracks, windows: the input artifacts.
        out_dir: the artifact's build folder.
        device: torch device for the force math (default CPU).
        on_sequence: called with (source:split, windows done) after each raw file (progress).
    """
    device = device or torch.device("cpu")
    dt_s = float(tracks.manifest.stats["dt_s"])
    obs_len, window_len = int(windows.manifest.stats["obs_len"]), int(windows.manifest.stats["window_len"])
    started = time.perf_counter()
    track_table = pq.read_table(tracks.file(TRACKS_FILE), columns=["source", "split", "step", "ped_id", "x", "y"])
    sequences = _sequences(track_table.to_pandas(), cfg)
    window_table = pq.read_table(
        windows.file(WINDOWS_FILE), columns=["benchmark", "part", "window_id", "source", "split", "first_step"]
    ).to_pandas()
    agents = pq.read_table(
        windows.file(AGENT_WINDOWS_FILE), columns=["benchmark", "part", "window_id", "ped_id"]
    ).to_pandas()
    setup_s = time.perf_counter() - started

    results: dict[tuple[str, str], _Features] = {}
    seconds: dict[str, float] = {}
    distinct = window_table.drop_duplicates(["source", "split", "first_step"])
    for (source, split), starts in distinct.groupby(["source", "split"], observed=True, sort=True):
        tic = time.perf_counter()
        key = (str(source), str(split))
        results[key] = _compute_sequence(
            sequences[key],
            np.sort(starts["first_step"].to_numpy()),
            cfg,
            dt_s=dt_s,
            obs_len=obs_len,
            window_len=window_len,
            device=device,
        )
        seconds[f"{source}:{split}"] = time.perf_counter() - tic
        if on_sequence:
            on_sequence(f"{source}:{split}", len(starts))

    rows, arrays = _scatter(results, window_table, agents)
    for name, filename in FORCES_ARRAYS.items():
        np.save(out_dir / filename, arrays[name])
    pq.write_table(
        pa.Table.from_pandas(agents[["benchmark", "part", "window_id", "ped_id"]], preserve_index=False),
        out_dir / FORCES_INDEX_FILE,
    )
    return {
        "summary": _summary(rows, results, arrays, seconds),
        "seconds_total": time.perf_counter() - started,
        "seconds_setup": setup_s,
        "seconds_per_sequence": seconds,
        "distinct_agent_windows": int(sum(r.first_step.size for r in results.values())),
        "dt_s": dt_s,
        "obs_len": obs_len,
    }


def _summary(
    rows: pd.DataFrame,
    results: dict[tuple[str, str], _Features],
    arrays: dict[str, np.ndarray],
    seconds: dict[str, float],
) -> list[dict[str, Any]]:
    """Per benchmark part: mean |F_dr|, |F_re|, share of pairs grouped, compute time of its files."""
    dr_norm = np.linalg.norm(arrays["f_dr"], axis=-1).mean(axis=1)  # (M,) mean over steps
    re_norm = np.linalg.norm(arrays["f_re"], axis=-1).mean(axis=1)
    summary = []
    for (benchmark, part), group in rows.groupby(["benchmark", "part"], observed=True, sort=False):
        index = group.index.to_numpy()  # rows keep agent_windows order
        members = set(zip(group["source"], group["split"]))
        pairs = sum(results[m].pairs for m in members)
        grouped = sum(results[m].grouped_pairs for m in members)
        summary.append(
            {
                "benchmark": str(benchmark),
                "part": str(part),
                "agent_windows": int(index.size),
                "mean_abs_f_dr": float(dr_norm[index].mean()),
                "mean_abs_f_re": float(re_norm[index].mean()),
                "grouped_pair_share": grouped / pairs if pairs else 0.0,
                "seconds": sum(seconds[f"{s}:{p}"] for s, p in members),
            }
        )
    return summary


def build(cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: StageContext) -> dict[str, Any]:
    """The stage contract: social forces of every agent-window, one recording at a time."""
    total = len({source for row in inputs["windows"].manifest.stats["summary"] for source in row["sources"]})
    done = iter(range(1, total + 1))
    return compute(
        cfg.forces,
        inputs["tracks"],
        inputs["windows"],
        ctx.dir,
        device=ctx.device(),
        on_sequence=lambda name, _: ctx.on_progress(f"social forces: {name}", next(done), total),
    )


STAGE = Stage(
    NAME,
    VERSIONS[NAME],
    COMMANDS[NAME],
    label="social forces",
    declare=lambda cfg: Reads(params=("forces.*",), artifacts={"tracks": None, "windows": None}),
    build=build,
    section="forces",
    parts=ARRAY_PARAMS,
)
