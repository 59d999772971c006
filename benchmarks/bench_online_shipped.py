"""Latency of `OnlinePredictor.update` with the shipped models, against a reference revision in the same run.

The path a planner takes: `OnlinePredictor("cpu/zara1/dr")` by name, one torch thread, K = 20, a stream of
walkers at the model's 0.4 s step (benchmarks/bench_online.py's plaza), at 1, 10 and 50 agents; goal variants
with their goals drawn by the shipped goal U-Net ("sampled") or passed by the planner ("passed"). Every
update is timed whole (checking, buffer, grid, goals, encoder, decoder, the most-likely future) once agents
have a full history, from the second such update on (the first warms up).

The reference is a git revision of fftool (default: the last commit before the sampling speed-ups), checked out
in a temporary worktree and run by the same code in its own processes, alternating with this checkout round by
round, so both see the same machine state. Both load the same shipped weights (this checkout's models/).

    OMP_NUM_THREADS=1 python benchmarks/bench_online_shipped.py --out benchmarks/results/online_shipped.md
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_online import STEP_S, walkers  # the same plaza (a script's own folder is on its path)

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = "984b19e"  # the eager path before the sampling speed-ups


def stream(name: str, agents: int, goals: str, updates: int) -> list[float]:
    """Seconds per predicting update of one stream (run inside a worker process)."""
    import torch

    from fftool.online import OnlinePredictor

    torch.set_num_threads(1)
    online = OnlinePredictor(name, k=20, seed=0)
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


def worker(cells: list[list], out: Path) -> None:
    """Time every cell (model, agents, goals, updates) in this process and write the latencies as JSON."""
    import fftool

    assert Path(fftool.__file__).is_relative_to(os.environ["PYTHONPATH"]), f"{fftool.__file__}: not the revision asked"
    out.write_text(json.dumps([stream(*cell) for cell in cells]))


def run_worker(source: Path, cells: list[list]) -> list[list[float]]:
    """The latencies of `cells` measured by the fftool in `source` (its src/ first on the path)."""
    with tempfile.TemporaryDirectory() as folder:
        result = Path(folder) / "latencies.json"
        env = os.environ | {
            "PYTHONPATH": str(source / "src"),
            "OMP_NUM_THREADS": "1",
            "FFTOOL_MODELS": str(ROOT / "models"),
        }
        command = [sys.executable, __file__, "--worker", json.dumps(cells), "--result", str(result)]
        subprocess.run(command, env=env, check=True, cwd=folder)
        return json.loads(result.read_text())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", default="cpu/zara1/dr,cpu/zara1/baseline")
    parser.add_argument("--agents", default="1,10,50")
    parser.add_argument("--updates", type=int, default=40, help="predicting updates per stream and round")
    parser.add_argument("--rounds", type=int, default=3, help="alternations of the two revisions")
    parser.add_argument("--reference", default=REFERENCE, help="the git revision to compare with")
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
        reference = Path(folder) / "reference"
        subprocess.run(
            ["git", "worktree", "add", "--detach", "-q", str(reference), args.reference], cwd=ROOT, check=True
        )
        try:
            new: list[list[float]] = [[] for _ in cells]
            old: list[list[float]] = [[] for _ in cells]
            for round_ in range(args.rounds):
                for source, into in ((reference, old), (ROOT, new)):
                    for pooled, times in zip(into, run_worker(source, cells)):
                        pooled.extend(times)
                print(f"round {round_ + 1} of {args.rounds} done", file=sys.stderr, flush=True)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(reference)], cwd=ROOT, check=True)
    lines = [
        f"`OnlinePredictor(model).update`, K = 20, one thread; {args.reference} (before) against {head.strip()} "
        f"(after), {args.rounds} alternating rounds; milliseconds per update.",
        "",
        "| model | agents | goals | before: median / p99 | after: median / p99 | speed-up (medians) |",
        "|---|---:|---|---:|---:|---:|",
    ]
    for (name, agents, goals, _), before, after in zip(cells, old, new):
        b, a = np.array(before) * 1e3, np.array(after) * 1e3
        lines.append(
            f"| {name} | {agents} | {goals} | {np.median(b):.1f} / {np.percentile(b, 99):.1f} | "
            f"{np.median(a):.1f} / {np.percentile(a, 99):.1f} | {np.median(b) / np.median(a):.2f} |"
        )
    print("\n".join(lines))
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
