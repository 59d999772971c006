"""What a goal variant's decoder adds to the curve its output is a residual over, under the fair protocol.

dr and re output a residual over the constant-acceleration curve to their goal (`cvae.output =
"goal_residual"`) and decode each of the goal module's K goals from the prior's mean code. This scores each
shipped model of that kind as `fftool models validate` does (its own validation windows, the profile's shipped
goal U-Net's goals, its profile's code) with the decoder's output head scaled by each factor α: 1 is the model as
shipped, 0 the curve alone (no network). Reads no test window.

    fftool models install && fftool ingest -c pipelines/cpu.toml && fftool forces -c pipelines/cpu.toml
    fftool maps -c pipelines/cpu.toml && fftool sample-goals --benchmarks all -c pipelines/cpu.toml
    python benchmarks/fair_residual.py --benchmarks all --scales 1,0.5,0 --csv benchmarks/results/fair_residual_five.csv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd
import torch

from fftool import zoo
from fftool.artifacts.store import ArtifactStore
from fftool.config import EvaluateConfig, predictor_config, variant_section
from fftool.dataset.scenes import BENCHMARKS
from fftool.learning.cvae_model import load_model
from fftool.learning.fair_validation import fair_validation
from fftool.variants import reads_goal


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--benchmarks", default="all")
    parser.add_argument("--profile", default="cpu")
    parser.add_argument("--root", type=Path, default=Path("artifacts"))
    parser.add_argument("--scales", default="1,0.5,0", help="factors α of the decoder's output head")
    parser.add_argument("--csv", type=Path, required=True)
    args = parser.parse_args()
    benchmarks = BENCHMARKS if args.benchmarks == "all" else tuple(args.benchmarks.split(","))
    scales = [float(s) for s in args.scales.split(",")]
    cfg, source, rows = zoo.profile_config(args.profile), ArtifactStore(args.root), []
    for benchmark in benchmarks:
        goals = source.lookup("goals", zoo.chain(cfg, "goals", None, benchmark)["goals"].fingerprint)
        if goals is None:
            sys.exit(f"{args.root}: no goals of {benchmark}; run fftool sample-goals -c pipelines/{args.profile}.toml")
        for model in zoo.shipped(args.profile, [benchmark]):
            if model.kind != "cvae" or model.variant is None or not reads_goal(model.variant):
                continue
            if load_model(model.artifact, torch.device("cpu")).config.output != "goal_residual":
                continue
            evaluate = variant_section(predictor_config(cfg, model.variant), "evaluate")
            assert isinstance(evaluate, EvaluateConfig)
            for scale in scales:
                found = fair_validation(
                    source, goals, model.artifact, None, torch.device("cpu"), evaluate.fair_code, None, scale
                )
                rows.append((benchmark, model.variant, model.artifact.id, found["code"], scale, found))
                print(
                    f"{benchmark} {model.variant} α={scale}: {found['min_ade_m']:.4f} / {found['min_fde_m']:.4f}",
                    file=sys.stderr,
                    flush=True,
                )
    table = pd.DataFrame(
        [
            (b, v, m, c, s, n["windows"], round(n["min_ade_m"], 4), round(n["min_fde_m"], 4))
            for b, v, m, c, s, n in rows
        ],
        columns=[
            "benchmark",
            "variant",
            "model",
            "code",
            "residual_scale",
            "val_windows",
            "fair_min_ade_m",
            "fair_min_fde_m",
        ],
    )
    table.to_csv(args.csv, index=False)
    print(table.to_string(index=False))


if __name__ == "__main__":
    main()
