"""Latency of one scene, K = 20, a shipped model: torch eager (`Model.predict`) against its ONNX export run by
onnxruntime, one thread each, at 1, 10 and 50 agents (medians and maxima of 10 calls after 2 warm-ups), and the
largest difference between the two (metres). Exports the model first (minutes) unless --onnx names an export.
The graph decodes the most-likely future too (one more code in the same rollout), which `Model.predict` does not:
the ratio is, if anything, against the graph (benchmarks/bench_online_shipped.py times the same work on both).

    OMP_NUM_THREADS=1 python benchmarks/bench_export.py --model cpu/zara1/baseline
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import onnxruntime
import torch

from fftool.api import load
from fftool.export import ONNX_FILE, export


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default="cpu/zara1/baseline", help="a shipped goal-free model with a DLow sampler")
    parser.add_argument("--onnx", type=Path, help="an export of that model (default: export it now)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    model = load(args.model)
    folder = args.onnx
    if folder is None:
        folder = Path(tempfile.mkdtemp()) / "export"
        began = time.perf_counter()
        export(model, folder, {"model": args.model, **model.fingerprints})
        print(f"export: {time.perf_counter() - began:.0f} s, {(folder / ONNX_FILE).stat().st_size / 1e6:.1f} MB")
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    options.log_severity_level = 3  # errors only: loading prints a warning per cast it cannot fold otherwise
    session = onnxruntime.InferenceSession(str(folder / ONNX_FILE), options, providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    print("| agents | torch median / max (ms) | onnxruntime median / max (ms) | ratio | largest difference (m) |")
    print("| ---: | ---: | ---: | ---: | ---: |")
    for agents in (1, 10, 50):
        walk = np.cumsum(rng.normal(0.3, 0.1, (1, agents, 8, 2)), 2) + rng.normal(0, 3, (1, agents, 1, 2))
        past, mask = walk.astype(np.float32), np.ones((1, agents), bool)
        eager, graph = [], []
        for _ in range(12):
            began = time.perf_counter()
            expected = model.predict(past, mask, k=model.sampler.k)
            eager.append(time.perf_counter() - began)
            began = time.perf_counter()
            got, _ = session.run(None, {"past": past, "agent_mask": mask})
            graph.append(time.perf_counter() - began)
        e, g = np.array(eager[2:]) * 1e3, np.array(graph[2:]) * 1e3
        print(
            f"| {agents} | {np.median(e):.1f} / {e.max():.1f} | {np.median(g):.1f} / {g.max():.1f} | "
            f"{np.median(e) / np.median(g):.2f} | {np.abs(got - expected).max():.1e} |"
        )


if __name__ == "__main__":
    main()
