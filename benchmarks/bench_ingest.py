"""Benchmark: ingest of all the real ETH/UCY data against plain pandas read_csv of the same files.

Run: `python3 -m nox -s bench` (or `python benchmarks/bench_ingest.py [--raw DIR] [--repeat N]`).
Times are medians over N in-process repeats after one warm-up; peak memory is the max RSS of a fresh
subprocess that runs the workload once, and the same for a subprocess that only imports (baseline).
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

DEFAULT_RAW = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "eth_ucy" / "raw"


def fftool_ingest(raw: Path) -> None:
    """The whole `fftool ingest`: hash inputs, validate 24 files, write tracks and windows artifacts."""
    from fftool import pipeline
    from fftool.artifacts.store import ArtifactStore
    from fftool.config import load_config

    with tempfile.TemporaryDirectory() as root:
        cfg = load_config(None, [f"data.raw_dir={str(raw)!r}"])
        pipeline.run(cfg, ArtifactStore(root), ["windows"])


def fftool_validate(raw: Path) -> None:
    """Only the parse + validation of the 24 files (the part comparable to read_csv)."""
    from fftool.dataset.rawfiles import read_raw
    from fftool.stages.tracks import raw_files

    for path in raw_files(raw).values():
        read_raw(path, frame_stride=10)


def pandas_read_csv(raw: Path) -> None:
    """The reference: read the same 24 files with pandas and nothing else."""
    import pandas as pd

    for path in sorted(raw.glob("*/*.txt")):
        pd.read_csv(path, sep=r"\s+", header=None)


WORKLOADS: dict[str, Callable[[Path], None]] = {
    "fftool ingest": fftool_ingest,
    "fftool validate only": fftool_validate,
    "pandas read_csv": pandas_read_csv,
}


def _time(func: Callable[[Path], None], raw: Path, repeat: int) -> float:
    func(raw)  # warm-up: imports, page cache
    samples = []
    for _ in range(repeat):
        start = time.perf_counter()
        func(raw)
        samples.append(time.perf_counter() - start)
    return statistics.median(samples)


def _peak_rss_mb(name: str | None, raw: Path) -> float:
    """Max RSS of a fresh interpreter running one workload (or only the imports when name is None)."""
    code = (
        "import sys, resource; sys.path.insert(0, sys.argv[1]); import bench_ingest as b;"
        "import pandas, pyarrow.parquet, fftool.pipeline;"
        f"name = {name!r};"
        "name and b.WORKLOADS[name](__import__('pathlib').Path(sys.argv[2]));"
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(Path(__file__).parent), str(raw)],
        capture_output=True,
        text=True,
        check=True,
    )
    return int(out.stdout.strip().splitlines()[-1]) / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--raw", type=Path, default=DEFAULT_RAW)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args()
    raw = args.raw.resolve()

    from rich.console import Console
    from rich.table import Table

    from fftool.ui import err_console

    # Memory first: Linux keeps ru_maxrss across fork+exec, so the subprocesses must start while this
    # process is still small.
    baseline = _peak_rss_mb(None, raw)
    results = {name: {"peak_rss_mb": _peak_rss_mb(name, raw)} for name in WORKLOADS}
    err_console.quiet = True  # keep stage logs out of the timing loop's output
    for name, func in WORKLOADS.items():
        results[name]["seconds"] = _time(func, raw, args.repeat)
    err_console.quiet = False
    reference = results["pandas read_csv"]["seconds"]
    ratio = results["fftool ingest"]["seconds"] / reference
    validate_ratio = results["fftool validate only"]["seconds"] / reference

    table = Table(title=f"ingest of {raw} (median of {args.repeat}, 24 files)")
    for column in ("workload", "time (s)", "× read_csv", "peak RSS (MB)", "RSS above imports (MB)"):
        table.add_column(column, justify="left" if column == "workload" else "right")
    for name, r in results.items():
        table.add_row(
            name,
            f"{r['seconds']:.3f}",
            f"{r['seconds'] / reference:.1f}",
            f"{r['peak_rss_mb']:.0f}",
            f"{r['peak_rss_mb'] - baseline:.0f}",
        )
    table.caption = (
        "ingest = hash 24 inputs + validate + tracks.parquet + windows for 5 benchmarks × 3 parts; "
        f"import-only baseline RSS {baseline:.0f} MB"
    )
    Console().print(table)
    report = {
        "raw": str(raw),
        "repeat": args.repeat,
        "baseline_rss_mb": baseline,
        "ratio_ingest_vs_read_csv": ratio,
        "ratio_validate_vs_read_csv": validate_ratio,
        **results,
    }
    report["max_rss_self_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
