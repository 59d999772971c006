"""Benchmark: the forces stage on all five benchmarks, and its speed-up over a per-pair Python loop.

Run: `python3 -m nox -s bench` (or `python benchmarks/bench_forces.py`). Measures, in one run:
1. the whole `forces` stage (all 70k distinct agent-windows of 15 benchmark parts): wall time, and the
   peak RSS of a fresh process that builds it;
2. on one recording (crowds_zara01, the zara1 test part): the batched torch computation against a
   straightforward per-pair Python/NumPy loop over windows × steps × agents × neighbours, with the same
   inputs, and the largest difference between their forces.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DEFAULT_RAW = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "eth_ucy" / "raw"


def _stage(raw: Path, root: Path) -> tuple[dict, float]:
    from fftool import pipeline
    from fftool.artifacts.store import ArtifactStore
    from fftool.config import load_config

    cfg = load_config(None, [f"data.raw_dir={str(raw)!r}"])
    store = ArtifactStore(root)
    built = pipeline.run(cfg, store, ["windows"])
    start = time.perf_counter()
    built = pipeline.run(cfg, store, ["forces"])
    return built, time.perf_counter() - start


def reference_loop(position, velocity, speed0, goal, groups, cfg) -> tuple[np.ndarray, np.ndarray]:
    """F_dr, F_re (N, T, 2) of one window with plain Python loops over steps, agents and neighbours."""
    n, steps, _ = position.shape
    f_dr, f_re = np.zeros((n, steps, 2)), np.zeros((n, steps, 2))
    cos_half = math.cos(math.radians(cfg.fov_deg / 2))
    for t in range(steps):
        directions = []
        for a in range(n):
            offset = goal[a] - position[a, t]
            length = float(np.hypot(*offset))
            directions.append(offset / length if length >= cfg.goal_min_distance_m else None)
        for a in range(n):
            e_a = directions[a]
            if e_a is None:
                continue
            f_dr[a, t] = (speed0[a, t] * e_a - velocity[a, t]) / cfg.tau_s
            for b in range(n):
                if b == a or groups[a, b]:
                    continue
                e_b = directions[b] if directions[b] is not None else np.zeros(2)
                step = float(np.hypot(*velocity[b, t])) * cfg.ellipse_step_s
                r = position[a, t] - position[b, t]
                ahead = r - step * e_b
                n1, n2 = float(np.hypot(*r)), float(np.hypot(*ahead))
                radicand = (n1 + n2) ** 2 - step**2
                if radicand <= 1e-8:
                    continue
                semi_minor = 0.5 * math.sqrt(radicand)
                value = cfg.v0_m2_s2 * math.exp(-semi_minor / cfg.sigma_m)
                unit_r = r / n1 if n1 > 0 else np.zeros(2)
                unit_ahead = ahead / n2 if n2 > 0 else np.zeros(2)
                force = value / cfg.sigma_m * (n1 + n2) / (4 * semi_minor) * (unit_r + unit_ahead)
                toward = -force if cfg.fov_reading == "force" else -r
                in_view = float(e_a @ toward) >= float(np.hypot(*toward)) * cos_half
                f_re[a, t] += (1.0 if in_view else cfg.fov_out_of_view) * force
    return f_dr, f_re


def _subset(raw: Path) -> dict:
    """zara1's test recording: batched torch vs the reference loop, same inputs."""
    import pyarrow.parquet as pq
    import torch

    from fftool.config import ForcesConfig, IngestConfig
    from fftool.science.social_forces import desired_speed, finite_difference_velocity, same_group
    from fftool.stages import forces
    from fftool.stages.tracks import ingest_raw as ingest_build

    cfg = ForcesConfig()
    with tempfile.TemporaryDirectory() as tmp:
        ingest_build(IngestConfig(), raw, Path(tmp))
        tracks = pq.read_table(Path(tmp) / "tracks.parquet").to_pandas()
    tracks = tracks[(tracks["source"] == "crowds_zara01") & (tracks["split"] == "all")]
    seq = forces._sequences(tracks.reset_index(drop=True), cfg)[("crowds_zara01", "all")]
    valid_start = (
        np.flatnonzero(np.lib.stride_tricks.sliding_window_view(seq.present, 20, axis=1).all(-1).any(0))
        + seq.first_step
    )
    start = time.perf_counter()
    batched = forces._compute_sequence(
        seq, valid_start, cfg, dt_s=0.4, obs_len=8, window_len=20, device=torch.device("cpu")
    )
    batched_s = time.perf_counter() - start

    row_of = {(int(f), int(p)): i for i, (f, p) in enumerate(zip(batched.first_step, batched.ped_id))}
    start = time.perf_counter()
    worst, n_agent_windows = 0.0, 0
    for first in valid_start:
        steps = first - seq.first_step + np.arange(20)
        valid = seq.present[:, steps].all(axis=1)
        position = seq.position[valid][:, steps]  # (N, 20, 2)
        pos_t = torch.as_tensor(position)[None]
        present = torch.ones(pos_t.shape[:3], dtype=torch.bool)
        velocity = finite_difference_velocity(pos_t, present, 0.4, 8)
        speed0 = desired_speed(velocity, present, 8, cfg)[0].numpy()
        labels = torch.as_tensor(seq.label[valid][:, steps[:8]])[None]
        groups = same_group(labels, cfg.group_min_steps)[0].numpy()
        f_dr, f_re = reference_loop(position, velocity[0].numpy(), speed0, position[:, -1], groups, cfg)
        rows = [row_of[(int(first), int(p))] for p in seq.ped_id[valid]]
        worst = max(
            worst,
            float(np.abs(batched.arrays["f_dr"][rows] - f_dr).max()),
            float(np.abs(batched.arrays["f_re"][rows] - f_re).max()),
        )
        n_agent_windows += len(rows)
    loop_s = time.perf_counter() - start
    return {
        "agent_windows": n_agent_windows,
        "batched_s": batched_s,
        "loop_s": loop_s,
        "speedup": loop_s / batched_s,
        "max_abs_difference": worst,
    }


def _peak_rss_mb(raw: Path) -> float:
    code = (
        "import sys, tempfile, resource; sys.path.insert(0, sys.argv[1]); import bench_forces as b;"
        "from pathlib import Path; d = tempfile.mkdtemp(); b._stage(Path(sys.argv[2]), Path(d));"
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(Path(__file__).parent), str(raw)], capture_output=True, text=True, check=True
    )
    return int(out.stdout.strip().splitlines()[-1]) / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--raw", type=Path, default=DEFAULT_RAW)
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args()
    raw = args.raw.resolve()

    from rich.console import Console
    from rich.table import Table

    from fftool.ui import err_console

    peak = _peak_rss_mb(raw)  # first, while this process is small (ru_maxrss survives fork+exec)
    err_console.quiet = True
    with tempfile.TemporaryDirectory() as root:
        built, stage_s = _stage(raw, Path(root))
        stats = built["forces"].manifest.stats
    subset = _subset(raw)
    err_console.quiet = False

    table = Table(title="forces benchmark")
    table.add_column("measurement")
    table.add_column("value", justify="right")
    table.add_row("whole forces stage, 15 parts (s)", f"{stage_s:.1f}")
    table.add_row("  distinct agent-windows", f"{stats['distinct_agent_windows']:,}")
    table.add_row("  of which setup + DBSCAN (s)", f"{stats['seconds_setup']:.1f}")
    table.add_row("  peak RSS of a process ingesting + building it (MB)", f"{peak:.0f}")
    table.add_row(
        f"zara1 test, {subset['agent_windows']:,} agent-windows: batched torch (s)", f"{subset['batched_s']:.2f}"
    )
    table.add_row("  per-pair Python/NumPy loop (s)", f"{subset['loop_s']:.1f}")
    table.add_row("  speed-up", f"{subset['speedup']:.0f}×")
    table.add_row("  max |difference| (m/s²)", f"{subset['max_abs_difference']:.1e}")
    Console().print(table)
    if args.json:
        report = {"stage_s": stage_s, "peak_rss_mb": peak, "distinct_agent_windows": stats["distinct_agent_windows"]}
        args.json.write_text(json.dumps({**report, "subset": subset}, indent=2))


if __name__ == "__main__":
    main()
