"""Latency of `fftool.online.OnlinePredictor.update` over a long stream, and its memory over 10,000 updates.

Each update hands the predictor one frame of detections (agents walking in a plaza, every agent in view
throughout, at the model's 0.4 s step) and times the whole call: checking the detections, the buffer,
putting the tracks on the grid, desired speeds and groups, the encoder and K autoregressive decoder passes
(the social forces recomputed at every step for dr). The first `obs_len` updates predict nothing and are
left out. Models are randomly initialised with the `[cvae]` sizes of pipelines/quick.toml and
pipelines/paper.toml (latency does not depend on the weights); goal variants get each agent's goal.
`--memory N` instead feeds N updates of a crowd that keeps changing (agents enter and leave) to the quick
model and reports the process's resident memory as it goes.
Run: `OMP_NUM_THREADS=1 python benchmarks/bench_online.py --threads 1`.
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import numpy as np
import torch

PIPELINES = Path(__file__).resolve().parents[1] / "pipelines"
STEP_S = 0.4


def walkers(agents: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Start points (A, 2) on a 0.8 m lattice and velocities (A, 2) in m/s, crossing a 20 m plaza."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(agents)))
    start = np.stack(np.divmod(np.arange(agents), side), -1) * 0.8
    heading = rng.uniform(0, 2 * np.pi, agents)
    return start.astype(np.float64), 1.2 * np.column_stack([np.cos(heading), np.sin(heading)])


def model_of(profile: str, variant: str) -> object:
    from fftool.api import Model
    from fftool.config import ForcesConfig, load_config
    from fftool.learning.cvae_model import Trained, build_model

    cfg = load_config(PIPELINES / f"{profile}.toml").cvae.model_copy(update={"variant": variant})
    torch.manual_seed(0)
    net = build_model(cfg).eval()
    return Model(Trained(net, cfg, ForcesConfig(), STEP_S), 8, 12, torch.device("cpu"))


def matmul_gflops(tokens: int = 200, d_model: int = 64, repeats: int = 2000) -> float:
    """The rate (GFLOP/s) one thread reaches on the decoder's typical product: `tokens` rows (K = 20 samples of
    10 agents) through a fused 5-way projection of width d_model, the upper bound the model's products approach."""
    x, w = torch.randn(tokens, d_model), torch.randn(5 * d_model, d_model)
    for _ in range(50):
        torch.nn.functional.linear(x, w)
    began = time.perf_counter()
    for _ in range(repeats):
        torch.nn.functional.linear(x, w)
    return 2 * tokens * d_model * 5 * d_model * repeats / (time.perf_counter() - began) / 1e9


def update_gflop(model: object, agents: int, k: int) -> float:
    """Floating-point work of one predicting update (torch.utils.flop_counter: matrix products)."""
    from torch.utils.flop_counter import FlopCounterMode

    from fftool.online import OnlinePredictor

    online = OnlinePredictor(model, k=k, seed=0)
    start, velocity = walkers(agents)
    goals = dict(enumerate(map(tuple, start + 20 * velocity)))
    for frame in range(model.obs_len):
        t = frame * STEP_S
        detections = dict(enumerate(map(tuple, start + t * velocity)))
        if frame == model.obs_len - 1:
            with FlopCounterMode(display=False) as counter:
                online.update(t, detections, goals=goals)
            return counter.get_total_flops() / 1e9
        online.update(t, detections, goals=goals)
    raise AssertionError("unreachable")


def latencies(model: object, agents: int, updates: int, k: int) -> np.ndarray:
    """Seconds per predicting update of a stream of `updates` frames."""
    from fftool.online import OnlinePredictor
    from fftool.variants import reads_goal

    online = OnlinePredictor(model, k=k, seed=0)
    start, velocity = walkers(agents)
    ids = list(range(agents))
    goals = dict(zip(ids, map(tuple, start + 20 * velocity))) if reads_goal(model.variant) else None
    times = []
    for frame in range(updates + model.obs_len - 1):
        t = frame * STEP_S
        detections = dict(zip(ids, map(tuple, start + t * velocity)))
        began = time.perf_counter()
        result = online.update(t, detections, goals=goals)
        elapsed = time.perf_counter() - began
        if frame >= model.obs_len - 1:
            assert len(result.agents) == agents
            times.append(elapsed)
    return np.array(times)


def rss_mib() -> float:
    """The process's resident memory now (Linux /proc), in MiB."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * resource.getpagesize() / 2**20


def memory(updates: int, k: int) -> None:
    """RSS every updates/10 updates of a changing crowd (20 in view, one replaced every 5 s, 20 % of frames missed)."""
    from fftool.online import OnlinePredictor

    online = OnlinePredictor(model_of("quick", "dr"), k=k, seed=0)
    rng = np.random.default_rng(0)
    print("| updates | agents buffered | detections buffered | RSS (MiB) |")
    print("|---:|---:|---:|---:|")
    for frame in range(updates):
        t = frame * STEP_S
        in_view = np.arange(frame // 12, frame // 12 + 20)
        seen = in_view[rng.random(20) > 0.2]
        detections = {int(a): (0.8 * float(a % 20), 1.2 * t - 4.8 * float(a)) for a in seen}  # walking up in lanes
        online.update(t, detections, goals={a: (x, y + 10.0) for a, (x, y) in detections.items()})
        if (frame + 1) % max(updates // 10, 1) == 0:
            buffer = online.buffer
            print(f"| {frame + 1:,} | {len(buffer.agents)} | {len(buffer.time)} | {rss_mib():.1f} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--variant", default="dr", help="baseline, goal, dr or re (default: dr)")
    parser.add_argument("--agents", default="1,10,50")
    parser.add_argument("--profiles", default="quick,paper")
    parser.add_argument("--k", type=int, default=20)
    parser.add_argument("--updates", type=int, default=300, help="predicting updates per stream (quick size)")
    parser.add_argument("--paper-updates", type=int, default=60, help="predicting updates per stream (paper size)")
    parser.add_argument("--memory", type=int, default=0, help="instead: RSS over this many updates")
    parser.add_argument("--out", type=Path, help="also write the latency table here (markdown)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} thread(s), K = {args.k}")
    if args.memory:
        memory(args.memory, args.k)
        return
    print(f"variant {args.variant}, {args.updates} predicting updates per stream (paper size: --paper-updates)")
    rates = {
        profile: matmul_gflops(d_model=model_of(profile, "baseline").trained.config.d_model)
        for profile in args.profiles.split(",")
    }
    print("one thread's matrix-product rate:", ", ".join(f"{p} {r:.1f} GFLOP/s" for p, r in rates.items()))
    lines = [
        "| model | agents | median (ms) | 99th percentile (ms) | min (ms) | GFLOP per update | floor (ms) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    print("\n".join(lines))
    for profile in args.profiles.split(","):
        model = model_of(profile, args.variant)
        for agents in (int(a) for a in args.agents.split(",")):
            updates = args.updates if profile == "quick" else args.paper_updates
            ms = latencies(model, agents, updates, args.k) * 1e3
            work = update_gflop(model, agents, args.k)
            cfg = model.trained.config
            label = f"{profile} (d_model {cfg.d_model}, {cfg.n_layers} layers)"
            row = f"| {label} | {agents} | {np.median(ms):.1f} | {np.percentile(ms, 99):.1f} | {ms.min():.1f} |"
            lines.append(f"{row} {work:.2f} | {work / rates[profile] * 1e3:.1f} |")
            print(lines[-1], flush=True)
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
