"""Latency of `OnlinePredictor.update` with the shipped models: torch's eager path against each model's export run
by onnxruntime, in the same run.

The path a planner takes: `OnlinePredictor("cpu/zara1/dr")` by name, one thread, K = 20, a stream of walkers at
the model's 0.4 s step (benchmarks/bench_online.py's plaza), at 1, 10 and 50 agents; goal variants with their
goals drawn by the shipped goal U-Net ("sampled") or passed by the planner ("passed"). Every update is timed
whole (checking, buffer, grid, goals, encoder, decoder; the eager path's most-likely future too) once agents
have a full history, from the second such update on (the first warms up).

Each model is exported first (`fftool export`, about a minute each); `OnlinePredictor(folder)` then runs the same
streams on the export, with onnxruntime on one thread. Both paths run in processes of their own, alternating
round by round, so both see the same machine state.

    OMP_NUM_THREADS=1 python benchmarks/bench_online_shipped.py --out benchmarks/results/online_shipped.md
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_online import STEP_S, walkers  # the same plaza (a script's own folder is on its path)

ROOT = Path(__file__).resolve().parents[1]


def stream(name: str, agents: int, goals: str, updates: int) -> list[float]:
    """Seconds per predicting update of one stream (run inside a worker process); name: a shipped model's, or
    the folder of its export."""
    import torch

    from fftool.export import is_export
    from fftool.exported import ExportedModel
    from fftool.online import OnlinePredictor

    torch.set_num_threads(1)
    model = ExportedModel.load(name, threads=1) if is_export(Path(name)) else name  # one thread, as torch
    online = OnlinePredictor(model, k=20, seed=0)
    start, velocity = walkers(agents)
    ids = list(range(agents))
    passed = dict(zip(ids, map(tuple, start + 5 * velocity))) if goals == "passed" else None
    times = []
    for frame in range(updates + 8):  # the first predicting update (the 8th) warms up and is not counted
        t = frame * STEP_S
        detections = dict(zip(ids, map(tuple, start + t * velocity)))
        began = time.perf_counter()
        result = online.update(t, detections, goals=passed)
        if frame >= 8:
            times.append(time.perf_counter() - began)
            assert len(result.agents) == agents
    return times


def cpu_name() -> str:
    """The processor's model name (latencies depend on it more than on anything else here)."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
        return next(line.split(":", 1)[1].strip() for line in lines if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or platform.machine()


def export_all(names: list[str], folder: Path) -> dict[str, str]:
    """Each shipped model exported by this checkout into `folder`: name -> export folder."""
    from fftool.api import load, load_goal_sampler
    from fftool.export import export
    from fftool.variants import reads_goal

    folders = {}
    for name in names:
        model = load(name)
        goals = load_goal_sampler(name) if reads_goal(model.variant) else None
        out = folder / name.replace("/", "_")
        began = time.perf_counter()
        export(model, out, {"model": name, **model.fingerprints}, goals)
        print(f"exported {name}: {time.perf_counter() - began:.0f} s", file=sys.stderr, flush=True)
        folders[name] = str(out)
    return folders


def worker(cells: list[list], out: Path) -> None:
    """Time every cell (model, agents, goals, updates) in this process and write the latencies as JSON."""
    out.write_text(json.dumps([stream(*cell) for cell in cells]))


def run_worker(cells: list[list]) -> list[list[float]]:
    """The latencies of `cells`, measured in a process of their own."""
    with tempfile.TemporaryDirectory() as folder:
        result = Path(folder) / "latencies.json"
        env = os.environ | {"OMP_NUM_THREADS": "1", "FFTOOL_MODELS": str(ROOT / "models")}
        command = [sys.executable, __file__, "--worker", json.dumps(cells), "--result", str(result)]
        subprocess.run(command, env=env, check=True, cwd=folder)
        return json.loads(result.read_text())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", default="cpu/zara1/dr,cpu/zara1/baseline")
    parser.add_argument("--agents", default="1,10,50")
    parser.add_argument("--updates", type=int, default=40, help="predicting updates per stream and round")
    parser.add_argument("--rounds", type=int, default=3, help="alternations of the two paths")
    parser.add_argument("--out", type=Path, help="also write the table here (markdown)")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument("--result", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(json.loads(args.worker), args.result)
        return
    from fftool.variants import reads_goal

    cells = []
    for name in args.models.split(","):
        for agents in map(int, args.agents.split(",")):
            for goals in ("sampled", "passed") if reads_goal(name.rsplit("/", 1)[-1]) else ("none",):
                updates = max(args.updates // (4 if agents >= 50 else 1), 5)
                cells.append([name, agents, goals, updates])
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    with tempfile.TemporaryDirectory() as folder:
        exports = export_all(args.models.split(","), Path(folder))
        exported_cells = [[exports[name], *rest] for name, *rest in cells]
        eager: list[list[float]] = [[] for _ in cells]
        graph: list[list[float]] = [[] for _ in cells]
        for round_ in range(args.rounds):
            for asked, into in ((cells, eager), (exported_cells, graph)):
                for pooled, times in zip(into, run_worker(asked)):
                    pooled.extend(times)
            print(f"round {round_ + 1} of {args.rounds} done", file=sys.stderr, flush=True)
    lines = [
        f"`OnlinePredictor(model).update`, K = 20, one thread, {head.strip()}: torch's eager path and the model's "
        f"export run by onnxruntime, {args.rounds} alternating rounds; milliseconds per update.",
        "",
        f"CPU: {cpu_name()}, {os.cpu_count()} cores",
        "",
        "| model | agents | goals | eager: median / p99 | onnxruntime: median / p99 | eager / onnxruntime (medians) |",
        "|---|---:|---|---:|---:|---:|",
    ]
    for (name, agents, goals, _), by_eager, by_graph in zip(cells, eager, graph):
        e, g = np.array(by_eager) * 1e3, np.array(by_graph) * 1e3
        lines.append(
            f"| {name} | {agents} | {goals} | {np.median(e):.1f} / {np.percentile(e, 99):.1f} | "
            f"{np.median(g):.1f} / {np.percentile(g, 99):.1f} | {np.median(e) / np.median(g):.2f} |"
        )
    print("\n".join(lines))
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
