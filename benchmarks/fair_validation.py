"""Validation minADE / minFDE of trained CVAEs under the fair protocol: sample k decodes the goal module's goal k.

The number a goal variant's best epoch is chosen by when it trains with `goal_training.source = "module"`,
computed here for any CVAE (for instance one trained with true goals) on the same validation windows (the
model's own fixed subset) and the same goals, so the two can be compared (`fftool.learning.fair_validation`,
which `fftool models validate` records for the shipped models). Reads no test window.

    python benchmarks/fair_validation.py --root R --goals goals/<id> cvae/<id> [dlow/<id> ...]

A DLow sampler (dlow/<id>) is scored over the CVAE it was trained on, on the sampler's own validation subset.
`--val-windows N` scores every model on the same N validation windows instead (drawn with the CVAE's seed).
`--residual-scale 0` scores the path a model's output is a residual over (its `cvae.output`), with no network.
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
    parser.add_argument("models", nargs="+", help="CVAE or DLow artifact ids (cvae/<id>, dlow/<id>)")
    parser.add_argument("--goals", required=True, help="the goals artifact (goals/<id>) of the same benchmark")
    parser.add_argument("--root", type=Path, default=Path("artifacts"))
    parser.add_argument(
        "--code", choices=("prior", "mean"), default="prior", help="evaluate.fair_code: the code each goal decodes with"
    )
    parser.add_argument(
        "--val-windows", type=int, help="score this many validation windows (the same for every model of a seed)"
    )
    parser.add_argument(
        "--residual-scale",
        type=float,
        default=1.0,
        help="the decoder's output head times this factor (0: the path its output is a residual over, no network)",
    )
    args = parser.parse_args()
    writer = csv.writer(sys.stdout)
    header = ["model", "variant", "benchmark", "best_epoch", "val_windows", "fair_min_ade_m", "fair_min_fde_m"]
    writer.writerow([*header, "output", "residual_scale"])
    store, goals = find_artifact(args.goals, "goals", args.root)
    for ref in args.models:
        dlow = find_artifact(ref, "dlow", args.root)[1] if str(ref).startswith("dlow/") else None
        found_cvae = store.lookup("cvae", dlow.manifest.built_from()["cvae"]) if dlow else None
        cvae = found_cvae if dlow else find_artifact(ref, "cvae", args.root)[1]
        if cvae is None:
            sys.exit(f"{ref}: the CVAE it samples from is not in {args.root}")
        found = fair_validation(
            store, goals, cvae, dlow, torch.device("cpu"), args.code, args.val_windows, args.residual_scale
        )
        stats = cvae.manifest.stats
        numbers = [f"{found['min_ade_m']:.4f}", f"{found['min_fde_m']:.4f}"]
        best = (dlow or cvae).manifest.stats["best_epoch"]
        row = [(dlow or cvae).id, stats["variant"], stats["benchmark"], best, found["windows"], *numbers]
        writer.writerow([*row, cvae.manifest.params["output"], args.residual_scale])


if __name__ == "__main__":
    main()
