"""Validation minADE / minFDE of trained CVAEs under the fair protocol: sample k decodes the goal module's goal k.

The number a goal variant's best epoch is chosen by when it trains with `goal_training.source = "module"`,
computed here for any CVAE (for instance one trained with true goals) on the same validation windows (the
model's own fixed subset) and the same goals, so the two can be compared (`fftool.learning.fair_validation`,
which `fftool models validate` records for the shipped models). Reads no test window.

    python benchmarks/fair_validation.py --root R --goals goals/<id> cvae/<id> [cvae/<id> ...]
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import torch

from fftool.api import find_artifact
from fftool.learning.fair_validation import fair_validation


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("models", nargs="+", help="CVAE artifact ids (cvae/<id>)")
    parser.add_argument("--goals", required=True, help="the goals artifact (goals/<id>) of the same benchmark")
    parser.add_argument("--root", type=Path, default=Path("artifacts"))
    args = parser.parse_args()
    writer = csv.writer(sys.stdout)
    writer.writerow(["cvae", "variant", "benchmark", "val_windows", "fair_min_ade_m", "fair_min_fde_m"])
    store, goals = find_artifact(args.goals, "goals", args.root)
    for ref in args.models:
        _, cvae = find_artifact(ref, "cvae", args.root)
        found = fair_validation(store, goals, cvae, None, torch.device("cpu"))
        stats = cvae.manifest.stats
        numbers = [f"{found['min_ade_m']:.4f}", f"{found['min_fde_m']:.4f}"]
        writer.writerow([cvae.id, stats["variant"], stats["benchmark"], found["windows"], *numbers])


if __name__ == "__main__":
    main()
