"""Benchmark: the suite's property tests run long, generating many more inputs per target.

Run: `python benchmarks/bench_fuzz.py [--examples 10000] [--only predict]`. The targets are the properties of
tests/test_track_files.py (the track reader: the grid at other rates, units and names; arbitrary tables; the
dataset TOML reader), of tests/test_predict.py (the API's door and `fftool predict`'s), of tests/test_online.py
(the online predictor's updates) and of tests/test_zoo.py (`fftool models install` of a damaged zoo); the suite
runs each with 40 examples.
Prints, per target, the inputs Hypothesis generated and tried, the failures it found, and the time, from
pytest's `--hypothesis-show-statistics`.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGETS = [
    "tests/test_track_files.py::test_the_grid_data_at_another_rate_unit_or_naming_gives_the_same_tracks",
    "tests/test_track_files.py::test_any_generated_table_is_read_or_refused_in_one_line",
    "tests/test_track_files.py::test_any_generated_dataset_toml_is_read_or_refused_in_one_line",
    "tests/test_predict.py::test_generated_api_input_gives_finite_futures_or_one_clear_error",
    "tests/test_predict.py::test_generated_track_files_and_options_give_a_forecast_or_one_error_line",
    "tests/test_online.py::test_generated_streams_give_finite_futures_or_one_clear_error_and_keep_the_state",
    "tests/test_zoo.py::test_generated_damage_to_a_zoo_is_refused_before_anything_is_installed",
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=10_000)
    parser.add_argument("--only", default="", help="run the targets whose name contains this")
    args = parser.parse_args()
    env = os.environ | {"FFTOOL_FUZZ_EXAMPLES": str(args.examples), "OMP_NUM_THREADS": "1"}
    print("| target | examples asked | outcome | time (s) |\n|---|---:|---|---:|")
    for target in (t for t in TARGETS if args.only in t):
        started = time.perf_counter()
        pytest = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--timeout=0"]
        done = subprocess.run(
            [*pytest, "--hypothesis-show-statistics", target],
            cwd=ROOT, env=env, capture_output=True, text=True,
        )  # fmt: skip
        seconds = time.perf_counter() - started
        passing = [line.strip() for line in done.stdout.splitlines() if " passing" in line]
        outcome = "passed" if done.returncode == 0 else "FAILED"
        print(f"| {target.split('::')[1]} | {args.examples} | {outcome}: {'; '.join(passing)} | {seconds:.0f} |")
        if done.returncode:
            print(done.stdout[-3000:])


if __name__ == "__main__":
    main()
