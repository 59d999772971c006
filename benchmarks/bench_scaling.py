"""Benchmark: parallel cells and thread settings on this machine, in one run.

Run: `python benchmarks/bench_scaling.py [--out benchmarks/results/scaling.md]` on an otherwise idle
machine (about 25 minutes on 2 cores). Two measurements, each from fresh artifact roots under a
temporary folder, with the real data:

1. The quick profile's zara1 grid end to end (`fftool reproduce pipelines/quick.toml --benchmarks zara1`)
   with `--jobs 1 --threads C` (C = the cores) and with `--jobs 2` (C/2 threads each): wall time and ratio,
   and whether the two runs' tables agree.
2. Two trainings at once (`fftool train-cvae`, the quick profile's baseline and goal variants, 2 epochs each,
   from shared prebuilt inputs) with torch's default threads in each (one per core) and with one thread
   each (OMP_NUM_THREADS=1): the wall time until both are done, beside one training alone.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FFTOOL = [str(Path(sys.executable).with_name("fftool"))]
QUICK = ROOT / "pipelines" / "quick.toml"


def _timed(commands: list[list[str]], env: dict[str, str], limit: float | None = None) -> float | None:
    """Wall seconds until every command (started together) has finished, or None when they ran past `limit`
    seconds (they are then killed); fails loudly on an error."""
    started = time.perf_counter()
    running = [subprocess.Popen(c, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE) for c in commands]
    for process, command in zip(running, commands, strict=True):
        try:
            _, err = process.communicate(
                timeout=None if limit is None else max(1.0, limit - (time.perf_counter() - started))
            )
        except subprocess.TimeoutExpired:
            for other in running:
                other.kill()
                other.wait()
            return None
        if process.returncode:
            raise SystemExit(f"{' '.join(command)} failed:\n{err.decode()[-2000:]}")
    return time.perf_counter() - started


def _tables(report: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(report.glob("table*.csv"))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "scaling.md")
    parser.add_argument("--epochs", type=int, default=2, help="epochs of each concurrent training")
    parser.add_argument("--limit", type=float, default=600, help="seconds after which a concurrent run is stopped")
    parser.add_argument("--trainings-only", action="store_true", help="skip the grid (measurement 1)")
    args = parser.parse_args()
    cores = len(os.sched_getaffinity(0))
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
    lines = [
        f"# Scaling on this machine ({cores} cores)",
        "",
        f"Command: `python benchmarks/{Path(__file__).name}`",
        "",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        grid = {}
        for label, extra in (("--jobs 1", ["--threads", str(cores)]), ("--jobs 2", ["--jobs", "2"])):
            if args.trainings_only:
                break
            root = work / label.replace(" ", "").replace("-", "")
            command = [*FFTOOL, "reproduce", str(QUICK), "--benchmarks", "zara1", "--root", str(root), *extra]
            grid[label] = (_timed([command], env), root)
            print(f"{label}: {grid[label][0]:.0f} s", flush=True)
        if grid:
            one, two = grid["--jobs 1"][0], grid["--jobs 2"][0]
            reports = [grid[label][1] / "reports" / "quick" for label in grid]
            same = _tables(reports[0]) == _tables(reports[1])
            lines += [
                "## The quick profile's zara1 grid, end to end (ingest to tables)",
                "",
                "| run | wall time | ratio |",
                "|---|---:|---:|",
                f"| `--jobs 1 --threads {cores}` | {one / 60:.1f} min | 1.00 |",
                f"| `--jobs 2` ({max(1, cores // 2)} thread each) | {two / 60:.1f} min | {two / one:.2f} |",
                "",
                "Tables identical: "
                + ("yes." if same else "no: the thread counts differ, so float sums do (docs/scaling.md)."),
                "",
            ]
            shared = grid["--jobs 1"][1]  # tracks, windows, forces in it: the trainings below only train
        else:
            shared = work / "inputs"
            for stage in ("ingest", "forces"):
                _timed([[*FFTOOL, stage, "-c", str(QUICK), "--root", str(shared)]], env)
        trainings = {}
        for variant in ("baseline", "goal"):
            root = work / f"train-{variant}"
            shutil.copytree(shared, root, ignore=shutil.ignore_patterns("cvae", "evaluate", "reports", ".logs"))
            trainings[variant] = [
                *FFTOOL, "train-cvae", "-c", str(QUICK), "--benchmarks", "zara1", "--variant", variant,
                "--root", str(root), "--set", f"cvae.epochs={args.epochs}", "--device", "cpu",
            ]  # fmt: skip
        alone = _timed([trainings["baseline"]], env)
        _clear(work)
        single = _timed(list(trainings.values()), env | {"OMP_NUM_THREADS": "1"})
        _clear(work)
        default = _timed(list(trainings.values()), env, args.limit)
        print(f"alone {alone:.0f} s, two at one thread each {single:.0f} s, two at default threads {default} s")
        lines += [
            f"## Two CVAE trainings at once (quick profile, {args.epochs} epochs each, zara1)",
            "",
            "| threads | wall time until both are done |",
            "|---|---:|",
            f"| one training alone, default threads ({cores}) | {alone:.0f} s |",
            f"| two at once, `OMP_NUM_THREADS=1` each | {single:.0f} s |",
            f"| two at once, default threads ({cores} each: {2 * cores} on {cores} cores) | "
            + (f"{default:.0f} s |" if default else f"not done after {args.limit:.0f} s (stopped) |"),
            "",
        ]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines))
    print("\n".join(lines))


def _clear(work: Path) -> None:
    """Remove the trained CVAEs (and their scratch) so the next measurement trains again."""
    for root in work.glob("train-*"):
        for folder in ("cvae", ".scratch", ".incomplete"):
            shutil.rmtree(root / folder, ignore_errors=True)


if __name__ == "__main__":
    main()
