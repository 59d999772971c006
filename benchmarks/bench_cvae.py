"""Benchmark: CVAE training throughput, batched windows vs one window per step, same process and model.

Run: `python3 -m nox -s bench` (or `python benchmarks/bench_cvae.py [--seconds 90] [--variant baseline]
[--precision bf16] [--compile] [--by-agents 20] [--profile 6]`).
Both modes train the same d_model 256 model (AgentFormer's size, K = 20 best-of-K samples) on the same
random zara1 training windows for a fixed time budget and report valid agent-windows per second. The
official implementation's figure on this machine is 2.61 agent-windows/s (research/agentformer.md §10.1).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

DEFAULT_RAW = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "eth_ucy" / "raw"
OFFICIAL_AGENT_WINDOWS_PER_S = 2.61
# The official code's seconds per training step by agent count, zara1 config (research/agentformer.md §10.2).
OFFICIAL_STEP_S = {1: 0.32, 2: 0.44, 4: 0.97, 8: 1.34, 16: 3.53, 32: 14.9}


def _throughput(scenes, cfg, plan, seconds: float) -> tuple[float, int]:
    from fftool.config import ForcesConfig
    from fftool.learning import cvae_model
    from fftool.learning.features import prepare

    torch.manual_seed(0)
    model = cvae_model.build_model(cfg).train()
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    gen = torch.Generator().manual_seed(0)
    agents, start = 0, time.perf_counter()
    for members in plan:
        prepared = prepare(scenes.batch(members), cfg.variant, 8, rotate=True, generator=gen)
        loss = cvae_model.training_loss(model, prepared, cfg, ForcesConfig(), 0.4, gen).total
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        agents += int(prepared.agent_mask.sum())
        if time.perf_counter() - start > seconds:
            break
    return agents / (time.perf_counter() - start), agents


def _by_agents(scenes, cfg, seconds: float):
    """(agents, batched, one window per step) throughput on windows with exactly that many agents."""
    counts = scenes.agents()
    for agents in OFFICIAL_STEP_S:
        windows = np.flatnonzero(counts == agents)[:96]
        if len(windows) == 0:
            continue
        plan = scenes.plan(windows, cfg.batch_windows, cfg.max_agent_pairs, np.random.default_rng(0))
        batched = _throughput(scenes, cfg, plan, seconds)[0]
        single = _throughput(scenes, cfg, [np.array([w]) for w in windows], seconds)[0]
        yield agents, batched, single


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--raw", type=Path, default=DEFAULT_RAW)
    parser.add_argument("--seconds", type=float, default=90.0)
    parser.add_argument("--variant", default="baseline")
    parser.add_argument("--precision", choices=("fp32", "bf16"), default="fp32")
    parser.add_argument("--compile", action="store_true", help="torch.compile the layers (compile time counts)")
    parser.add_argument("--profile", type=int, default=0, metavar="N", help="only profile the first N batched steps")
    parser.add_argument("--by-agents", type=float, default=0, metavar="S", help="also S seconds per agent count")
    args = parser.parse_args()

    from rich.console import Console
    from rich.table import Table

    from fftool import pipeline
    from fftool.artifacts.store import ArtifactStore
    from fftool.config import CVAEConfig, load_config
    from fftool.learning.batches import load_scene_set
    from fftool.ui import err_console

    err_console.quiet = True
    with tempfile.TemporaryDirectory() as root:
        built = pipeline.run(
            load_config(None, [], {"data.raw_dir": str(args.raw.resolve())}), ArtifactStore(root), ["forces"]
        )
        scenes = load_scene_set(built["windows"], built["forces"], "zara1", "train")
    err_console.quiet = False
    cfg = CVAEConfig(variant=args.variant, precision=args.precision, compile=args.compile)
    rng = np.random.default_rng(0)
    order = rng.permutation(scenes.windows)
    batched_plan = scenes.plan(order, cfg.batch_windows, cfg.max_agent_pairs, rng)
    if args.profile:
        from torch.profiler import profile

        with profile() as prof:
            _throughput(scenes, cfg, batched_plan[: args.profile], float("inf"))
        print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=15))
        return
    single_plan = [np.array([w]) for w in np.concatenate(batched_plan)]  # the same windows, in the same order
    batched, n_batched = _throughput(scenes, cfg, batched_plan, args.seconds)
    single, n_single = _throughput(scenes, cfg, single_plan, args.seconds)

    options = f"{args.precision}{', compiled' if args.compile else ''}"
    table = Table(title=f"CVAE training throughput, {args.variant}, {options}, d_model 256, K = 20, zara1 train")
    for column in ("mode", "agent-windows / s", "agent-windows done", "× official"):
        table.add_column(column, justify="right" if column != "mode" else "left")
    table.add_row(
        "batched (≤ 32 windows, ≤ 4096 window·agent²)",
        f"{batched:.2f}",
        str(n_batched),
        f"{batched / OFFICIAL_AGENT_WINDOWS_PER_S:.1f}",
    )
    table.add_row("one window per step", f"{single:.2f}", str(n_single), f"{single / OFFICIAL_AGENT_WINDOWS_PER_S:.1f}")
    table.add_row("official AgentFormer (research/agentformer.md)", f"{OFFICIAL_AGENT_WINDOWS_PER_S:.2f}", "", "1.0")
    table.caption = f"batched / one-window ratio: {batched / single:.1f}×; each mode ran about {args.seconds:.0f} s"
    Console().print(table)
    if args.by_agents:
        table = Table(title="by agents per window (windows with exactly that many agents)")
        for column in ("agents", "batched aw/s", "one window aw/s", "official aw/s (§10.2)", "batched × official"):
            table.add_column(column, justify="right")
        for agents, batched, single in _by_agents(scenes, cfg, args.by_agents):
            official = agents / OFFICIAL_STEP_S[agents]
            ratio = batched / official
            table.add_row(str(agents), f"{batched:.1f}", f"{single:.1f}", f"{official:.2f}", f"{ratio:.1f}")
        Console().print(table)


if __name__ == "__main__":
    main()
