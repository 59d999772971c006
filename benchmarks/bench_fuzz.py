"""Benchmark: the suite's property tests run long, generating many more inputs per target.

Run: `python benchmarks/bench_fuzz.py [--examples 10000] [--only predict]`. The targets are the properties of
tests/test_track_files.py (the track reader: the grid at other rates, units and names; arbitrary tables; the
dataset TOML reader), of tests/test_predict.py (the API's door and `fftool predict`'s), of tests/test_online.py
(the online predictor's updates) and of tests/test_zoo.py (`fftool models install` of a damaged zoo); the suite
runs each with 40 examples.
Each target's row (test cases passed, failed and given up, seconds, threads, date) replaces its previous
one in benchmarks/results/fuzz.csv; the docs render that file. The counts come from Hypothesis's
observability records (one JSON line per test case run), which also count the properties that call an
inner `@given` function, where `--hypothesis-show-statistics` prints nothing.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
from filelock import FileLock

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "fuzz.csv"
TARGETS = [
    "tests/test_track_files.py::test_the_grid_data_at_another_rate_unit_or_naming_gives_the_same_tracks",
    "tests/test_track_files.py::test_any_generated_table_is_read_or_refused_in_one_line",
    "tests/test_track_files.py::test_any_generated_dataset_toml_is_read_or_refused_in_one_line",
    "tests/test_predict.py::test_generated_api_input_gives_finite_futures_or_one_clear_error",
    "tests/test_predict.py::test_generated_track_files_and_options_give_a_forecast_or_one_error_line",
    "tests/test_online.py::test_generated_streams_give_finite_futures_or_one_clear_error_and_keep_the_state",
    "tests/test_zoo.py::test_generated_damage_to_a_zoo_is_refused_before_anything_is_installed",
]


def _counts(storage: Path) -> dict[str, int]:
    """Test cases by outcome (passed, failed, gave_up) in the observability records under `storage`."""
    counts = {"passed": 0, "failed": 0, "gave_up": 0}
    for path in (storage / "observed").glob("*_testcases.jsonl"):
        for line in path.read_text().splitlines():
            case = json.loads(line)
            if case.get("type") == "test_case":
                counts[case["status"]] = counts.get(case["status"], 0) + 1
    return counts


def _record(row: dict[str, object]) -> None:
    """Replaces the target's row; a lock lets two copies of the benchmark (one per core) share the file."""
    with FileLock(f"{RESULTS}.lock"):
        frame = pd.read_csv(RESULTS) if RESULTS.exists() else pd.DataFrame(columns=list(row))
        frame = pd.concat([frame[frame["target"] != row["target"]], pd.DataFrame([row])], ignore_index=True)
        order = {target.split("::")[1]: i for i, target in enumerate(TARGETS)}
        frame.sort_values("target", key=lambda names: names.map(order)).to_csv(RESULTS, index=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=10_000)
    parser.add_argument("--only", default="", help="run the targets whose name contains this")
    args = parser.parse_args()
    for target in (t for t in TARGETS if args.only in t):
        started = time.perf_counter()
        with tempfile.TemporaryDirectory() as storage:
            env = os.environ | {
                "FFTOOL_FUZZ_EXAMPLES": str(args.examples), "OMP_NUM_THREADS": "1",
                "HYPOTHESIS_STORAGE_DIRECTORY": storage, "HYPOTHESIS_EXPERIMENTAL_OBSERVABILITY_NOCOVER": "1",
            }  # fmt: skip
            pytest = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--timeout=0"]
            done = subprocess.run([*pytest, target], cwd=ROOT, env=env, capture_output=True, text=True)
            counts = _counts(Path(storage))
        row = {
            "target": target.split("::")[1], "examples_asked": args.examples, "passed": counts["passed"],
            "failed": counts["failed"], "gave_up": counts["gave_up"],
            "outcome": "passed" if done.returncode == 0 else "FAILED",
            "seconds": round(time.perf_counter() - started), "threads": 1,
            "date": datetime.date.today().isoformat(),
        }  # fmt: skip
        _record(row)
        print(row, flush=True)
        if done.returncode:
            print(done.stdout[-3000:])


if __name__ == "__main__":
    main()
