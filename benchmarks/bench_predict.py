"""Prediction latency per scene: K = 20 futures for 1, 10 and 50 agents, quick and paper model sizes.

Times `fftool.api.Model.predict` (one call = one scene: desired speeds and groups from the observed
steps, encoder, K autoregressive decoder passes with the social forces recomputed at every step) on
straight walkers, so a robotics user can tell whether it fits a control loop. Models are randomly
initialised with the `[cvae]` sizes of pipelines/quick.toml and pipelines/paper.toml: latency does not
depend on the weights. Times are medians of `--repeats` calls after one warm-up, at `--threads` torch
threads (recorded in the output).
Run: `OMP_NUM_THREADS=1 python benchmarks/bench_predict.py --threads 1`.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch

PIPELINES = Path(__file__).resolve().parents[1] / "pipelines"


def scene(agents: int, obs_len: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(1, A, obs_len, 2) straight walkers 0.8 m apart, their mask and goals 5 m ahead."""
    rng = np.random.default_rng(0)
    start = np.column_stack([np.zeros(agents), np.arange(agents) * 0.8])
    velocity = rng.normal([1.2, 0.0], 0.2, size=(agents, 2)) * 0.4  # metres per 0.4 s step
    past = start[:, None] + np.arange(obs_len)[None, :, None] * velocity[:, None]
    return past[None], np.ones((1, agents), bool), (past[:, -1] + 5 * velocity / 0.4)[None]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--variant", default="dr", help="baseline, goal, dr or re (default: dr)")
    parser.add_argument("--agents", default="1,10,50")
    parser.add_argument("--k", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--out", type=Path, help="also write the table here (markdown)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    from fftool.api import Model
    from fftool.config import ForcesConfig, load_config
    from fftool.learning.cvae_model import Trained, build_model

    print(f"torch {torch.__version__}, {torch.get_num_threads()} thread(s), variant {args.variant}, K = {args.k}")
    lines = ["| model | parameters | agents | median latency (ms) | min (ms) |", "|---|---:|---:|---:|---:|"]
    print("\n".join(lines))
    for profile in ("quick", "paper"):
        cfg = load_config(PIPELINES / f"{profile}.toml").cvae.model_copy(update={"variant": args.variant})
        torch.manual_seed(0)
        net = build_model(cfg).eval()
        model = Model(Trained(net, cfg, ForcesConfig(), 0.4), 8, 12, torch.device("cpu"))
        size = sum(p.numel() for p in net.parameters())
        for agents in (int(a) for a in args.agents.split(",")):
            past, mask, goals = scene(agents)
            model.predict(past, mask, k=args.k, goals=goals)  # warm-up
            times = []
            for _ in range(args.repeats):
                started = time.perf_counter()
                model.predict(past, mask, k=args.k, goals=goals)
                times.append(time.perf_counter() - started)
            median, best = statistics.median(times) * 1e3, min(times) * 1e3
            label = f"{profile} (d_model {cfg.d_model}, {cfg.n_layers} layers)"
            lines.append(f"| {label} | {size:,} | {agents} | {median:.1f} | {best:.1f} |")
            print(lines[-1], flush=True)
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
