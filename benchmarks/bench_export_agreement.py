"""How closely an export run by onnxruntime follows the torch path, next to how much the torch path itself moves
when its inputs move by float rounding.

The planner's path: `OnlinePredictor` on a shipped goal variant by name (torch, eager) and on its `fftool export`
(onnxruntime), the same stream of walkers at the model's 0.4 s step (benchmarks/bench_online.py's plaza), K = 20,
one thread, goals passed by the planner `--ahead` seconds of walking ahead of each start, at 1, 10 and 50 agents.
For each (ahead, agents): the largest difference between the two paths' futures over 15 predicting updates, and
the largest difference between the torch path and the torch path fed the same detections moved by N(0, 1e-6 m)
(its sensitivity to rounding). A walker whose goal lies within the horizon reaches it and walks on: its driving
force turns on a millimetre there.

    OMP_NUM_THREADS=1 python benchmarks/bench_export_agreement.py --out benchmarks/results/export_agreement.md
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from bench_online import STEP_S, walkers  # the same plaza (a script's own folder is on its path)

from fftool.api import load, load_goal_sampler
from fftool.export import export
from fftool.exported import ExportedModel
from fftool.online import OnlinePredictor
from fftool.variants import reads_goal

UPDATES = 15


def differences(name: str, exported: ExportedModel, agents: int, ahead_s: float) -> tuple[float, float]:
    """(onnxruntime vs torch, torch vs torch on inputs moved by 1e-6 m): the largest differences of futures (m)."""
    torch_path, graph, moved = (OnlinePredictor(model, k=exported.k, seed=0) for model in (name, exported, name))
    start, velocity = walkers(agents)
    ids = list(range(agents))
    goals = dict(zip(ids, map(tuple, start + ahead_s * velocity)))
    rng = np.random.default_rng(0)
    graph_gap = rounding_gap = 0.0
    for frame in range(8 + UPDATES):  # the 8th update is the first with a full history
        xy = start + frame * STEP_S * velocity
        futures = torch_path.update(frame * STEP_S, dict(zip(ids, map(tuple, xy))), goals).futures
        by_graph = graph.update(frame * STEP_S, dict(zip(ids, map(tuple, xy))), goals).futures
        nudged = xy + rng.normal(0, 1e-6, xy.shape)
        by_moved = moved.update(frame * STEP_S, dict(zip(ids, map(tuple, nudged))), goals).futures
        graph_gap = max(graph_gap, float(np.abs(by_graph - futures).max(initial=0.0)))
        rounding_gap = max(rounding_gap, float(np.abs(by_moved - futures).max(initial=0.0)))
    return graph_gap, rounding_gap


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default="cpu/zara1/dr", help="a shipped goal variant")
    parser.add_argument("--onnx", type=Path, help="an export of that model (default: export it now)")
    parser.add_argument("--agents", default="1,10,50")
    parser.add_argument("--ahead", default="30,5", help="seconds of walking from each start to its goal")
    parser.add_argument("--out", type=Path, help="also write the table here (markdown)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    model = load(args.model)
    assert reads_goal(model.variant), f"{args.model}: a goal variant, whose goals the stream passes"
    folder = args.onnx
    if folder is None:
        folder = Path(tempfile.mkdtemp()) / "export"
        began = time.perf_counter()
        export(model, folder, {"model": args.model, **model.fingerprints}, load_goal_sampler(args.model))
        print(f"export: {time.perf_counter() - began:.0f} s")
    exported = ExportedModel.load(folder, threads=1)
    lines = [
        f"`{args.model}`, K = {exported.k}, goals passed, {UPDATES} updates per stream; the largest difference of "
        "futures (m).",
        "",
        "| goal ahead of start | agents | onnxruntime vs torch | torch vs torch, inputs moved by 1e-6 m |",
        "|---:|---:|---:|---:|",
    ]
    for ahead_s in map(float, args.ahead.split(",")):
        for agents in map(int, args.agents.split(",")):
            graph_gap, rounding_gap = differences(args.model, exported, agents, ahead_s)
            lines.append(f"| {ahead_s:g} s | {agents} | {graph_gap:.1e} | {rounding_gap:.1e} |")
            print(lines[-1], flush=True)
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
