"""Where a run's time went: every artifact's build time from its manifest, per benchmark and stage.

    python tools/stage_times.py --root artifacts --benchmarks eth,hotel    # Markdown table on stdout
    python tools/stage_times.py --root artifacts --benchmarks zara1 --csv times.csv   # and one row per build

Each manifest records `build_seconds` (the stage's own work) and the torch threads it ran on. The table
(`fftool.reporting.doc_tables.training_times_table`, which docs/results/cpu_all.md renders from the CSV) sums
build seconds times threads per benchmark in thread-minutes and, with `--jobs N`, gives the wall time a
perfect N-way schedule of one-thread jobs would need (the sum divided by N, or the longest single build if
that is larger). `--csv` also writes every build: stage, benchmark (empty for the shared data stages), wall
seconds, torch threads and ranks.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from fftool.artifacts.store import Manifest
from fftool.reporting.doc_tables import training_times_table


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
    builds = []
    for path in sorted(args.root.glob("*/*/manifest.json")):
        manifest = Manifest.from_json(path.read_text())
        benchmark = manifest.stats.get("benchmark") or manifest.params.get("benchmark")
        if benchmark is None or benchmark in chosen:
            builds.append({"stage": _label(manifest), "benchmark": benchmark or "",
                           "seconds": round(float(manifest.stats.get("build_seconds") or 0.0), 1),
                           "threads": manifest.threads(), "ranks": manifest.ranks()})  # fmt: skip
    frame = pd.DataFrame(builds, columns=["stage", "benchmark", "seconds", "threads", "ranks"])
    shared = frame[frame["benchmark"] == ""]
    print(training_times_table(frame[frame["benchmark"] != ""], args.jobs))
    shared_minutes = float((shared["seconds"] * shared["threads"] * shared["ranks"]).sum()) / 60
    print(f"\nShared data stages (tracks, windows, forces, maps): {shared_minutes:.1f} thread-minutes, once.")
    if args.csv:
        frame.sort_values(["benchmark", "stage"]).to_csv(args.csv, index=False)


if __name__ == "__main__":
    main()
