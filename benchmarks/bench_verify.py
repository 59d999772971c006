"""Benchmark: what re-hashing input artifacts costs each stage, on the real data's artifacts.

Run: `python benchmarks/bench_verify.py [--root artifacts] [--repeats 5]` after the README's main job
(any artifact root holding a complete chain). For every artifact in the store, the check a stage runs
before building from it (`ArtifactStore.check_inputs`: sha256 of every file, compared with the
manifest) is timed; the table gives, per consuming stage, the bytes it re-hashes and the median time,
beside the time that stage took to build (`stats.build_seconds`; older artifacts: the stage's own timer).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from fftool.artifacts.store import ArtifactStore
from fftool.pipeline import STAGES

ROOT = Path(__file__).resolve().parents[1]
BUILD_TIME_KEYS = ("build_seconds", "seconds_this_run", "seconds_total", "seconds")


def _median_seconds(store: ArtifactStore, artifact, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        store.check_inputs({artifact.kind: artifact}, {artifact.kind: "fftool"})
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=ROOT / "artifacts")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    store = ArtifactStore(args.root)
    newest = {artifact.kind: artifact for artifact in store.list()}  # one artifact per kind, the newest
    check = {kind: _median_seconds(store, artifact, args.repeats) for kind, artifact in newest.items()}
    size = {kind: sum(f["bytes"] for f in a.manifest.files.values()) for kind, a in newest.items()}

    table = Table(title=f"input verification per stage ({args.root}, median of {args.repeats})")
    for column in ("stage", "inputs re-hashed", "MB", "check (s)", "stage build (s)", "share"):
        table.add_column(column, justify="left" if column in ("stage", "inputs re-hashed") else "right")
    for name, stage in STAGES.items():
        inputs = [kind for kind in stage.inputs if kind in newest]
        if not inputs or name not in newest:
            continue
        seconds = sum(check[kind] for kind in inputs)
        stats = newest[name].manifest.stats
        build = next((stats[key] for key in BUILD_TIME_KEYS if isinstance(stats.get(key), (int, float))), None)
        share = f"{seconds / build:.2%}" if build else ""
        megabytes = sum(size[kind] for kind in inputs) / 1e6
        row = [name, ", ".join(inputs), f"{megabytes:.1f}", f"{seconds:.3f}", f"{build:.1f}" if build else "–", share]
        table.add_row(*row)
    Console(width=120).print(table)


if __name__ == "__main__":
    main()
