"""Where a run's time went: every artifact's build time from its manifest, per benchmark and stage.

    python tools/stage_times.py --root artifacts --benchmarks eth,hotel    # Markdown table on stdout
    python tools/stage_times.py --root artifacts --benchmarks zara1 --csv times.csv   # and one row per build

Each manifest records `build_seconds` (the stage's own work) and the torch threads it ran on. The table
sums build seconds times threads per benchmark (the thread-seconds a run costs, `Manifest.thread_seconds`)
and, with `--jobs N`, gives the wall time a perfect N-way schedule of one-thread jobs would need (the sum
divided by N, or the longest single build if that is larger). `--csv` also writes every build: stage,
benchmark (empty for the shared data stages), wall seconds, torch threads and ranks.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

import pandas as pd

from fftool.artifacts.store import Manifest


def _label(manifest: Manifest) -> str:
    stats, params = manifest.stats, manifest.params
    variant = stats.get("variant") or params.get("variant")
    protocol = stats.get("protocol")
    parts = [manifest.kind, variant if variant and manifest.kind != "goal" else None]
    parts.append(protocol if protocol not in (None, "none") else None)
    return " ".join(p for p in parts if p)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path("artifacts"))
    parser.add_argument("--benchmarks", default="eth,hotel,univ,zara1,zara2")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--csv", type=Path, help="also write one row per build here")
    args = parser.parse_args()
    chosen = args.benchmarks.split(",")
    rows: dict[str, dict[str, float]] = defaultdict(dict)
    shared = 0.0
    builds = []
    for path in sorted(args.root.glob("*/*/manifest.json")):
        manifest = Manifest.from_json(path.read_text())
        seconds = manifest.thread_seconds()
        benchmark = manifest.stats.get("benchmark") or manifest.params.get("benchmark")
        if benchmark is None or benchmark in chosen:
            builds.append({"stage": _label(manifest), "benchmark": benchmark or "",
                           "seconds": round(float(manifest.stats.get("build_seconds") or 0.0), 1),
                           "threads": manifest.threads(), "ranks": manifest.ranks()})  # fmt: skip
        if benchmark is None:
            shared += seconds  # tracks, windows, forces, maps: once for every benchmark
        elif benchmark in chosen:
            rows[benchmark][_label(manifest)] = rows[benchmark].get(_label(manifest), 0.0) + seconds
    labels = sorted({label for row in rows.values() for label in row})
    print("| stage | " + " | ".join(chosen) + " |")
    print("|---|" + "---:|" * len(chosen))
    for label in labels:
        cells = [f"{rows[b][label] / 60:.1f}" if label in rows[b] else "" for b in chosen]
        print(f"| {label} | " + " | ".join(cells) + " |")
    totals = [sum(rows[b].values()) for b in chosen]
    longest = [max(rows[b].values(), default=0.0) for b in chosen]
    print("| **sum (thread-minutes)** | " + " | ".join(f"**{t / 60:.1f}**" for t in totals) + " |")
    wall = [max(t / args.jobs, m) for t, m in zip(totals, longest)]
    print(f"| {args.jobs}-job wall, ideal (min) | " + " | ".join(f"{w / 60:.1f}" for w in wall) + " |")
    print(f"\nShared data stages (tracks, windows, forces, maps): {shared / 60:.1f} min, once. "
          f"All chosen benchmarks: {sum(totals) / 60:.1f} thread-minutes, {sum(wall) / 60:.1f} min at {args.jobs} "
          "jobs if each benchmark ran alone.")  # fmt: skip
    if args.csv:
        pd.DataFrame(builds).sort_values(["benchmark", "stage"]).to_csv(args.csv, index=False)


if __name__ == "__main__":
    main()
