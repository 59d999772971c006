"""The test part's fair numbers of dr and re with their decoder's output head scaled, beside the shipped models'.

An ablation read after every choice was made (no setting is chosen from it): `benchmarks/fair_residual.py`
found on validation that under the mean code the constant-acceleration curve to each goal, with no network
(α = 0), is level with dr and ahead of re on minADE and minFDE. This runs the `evaluate` stage's own scoring
(`stages.evaluate.sample_and_score`: every test agent-window, K = 20, the shipped goal U-Net's goals, the fair
protocol) with the head scaled by each α, so minADE, minFDE and the collisions (NC) compare with the reports'
rows; α = 1 reproduces them.

    fftool models install && fftool ingest -c pipelines/cpu.toml && fftool forces -c pipelines/cpu.toml
    fftool maps -c pipelines/cpu.toml && fftool sample-goals --benchmarks all -c pipelines/cpu.toml
    python benchmarks/fair_residual_test.py --benchmarks all --scales 0 --csv benchmarks/results/fair_residual_test.csv
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import pandas as pd
import torch

from fftool import zoo
from fftool.artifacts.store import ArtifactStore
from fftool.config import EvaluateConfig, predictor_config, variant_section
from fftool.dataset.scenes import BENCHMARKS
from fftool.learning.cvae_model import load_model, scale_output
from fftool.stages import evaluate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--benchmarks", default="all")
    parser.add_argument("--variants", default="dr,re", help="shipped goal variants whose output is goal_residual")
    parser.add_argument("--profile", default="cpu")
    parser.add_argument("--root", type=Path, default=Path("artifacts"))
    parser.add_argument("--scales", default="0", help="factors α of the decoder's output head (1: as shipped)")
    parser.add_argument("--csv", type=Path, required=True)
    args = parser.parse_args()
    benchmarks = BENCHMARKS if args.benchmarks == "all" else tuple(args.benchmarks.split(","))
    cfg, store, rows = zoo.profile_config(args.profile), ArtifactStore(args.root), []
    for benchmark in benchmarks:
        goals = store.lookup("goals", zoo.chain(cfg, "goals", None, benchmark)["goals"].fingerprint)
        if goals is None:
            sys.exit(f"{args.root}: no goals of {benchmark}; run fftool sample-goals -c pipelines/{args.profile}.toml")
        cvaes = {m.variant: m.artifact for m in zoo.shipped(args.profile, [benchmark]) if m.kind == "cvae"}
        for variant in args.variants.split(","):
            cvae = cvaes[variant]
            evaluate_cfg = variant_section(predictor_config(cfg, variant), "evaluate")
            assert isinstance(evaluate_cfg, EvaluateConfig)
            windows, forces = (store.lookup(kind, cvae.manifest.sources[kind]) for kind in ("windows", "forces"))
            for scale in (float(s) for s in args.scales.split(",")):
                evaluate.load_model = lambda artifact, device, scale=scale: scale_output(
                    load_model(artifact, device), scale
                )
                with tempfile.TemporaryDirectory() as out:
                    found = evaluate.sample_and_score(
                        evaluate_cfg, benchmark, windows, forces, cvae, goals, Path(out), torch.device("cpu")
                    )
                nc = found["nc"]["best_ade"]["ordered"]
                rows.append(
                    (benchmark, variant, cvae.id, scale, found["agent_windows"], found["min_ade"], found["min_fde"], nc)
                )
                print(f"{benchmark} {variant} α={scale}: {found['min_ade']:.4f} / {found['min_fde']:.4f}, NC {nc}",
                      file=sys.stderr, flush=True)  # fmt: skip
    table = pd.DataFrame(
        rows, columns=["benchmark", "variant", "model", "residual_scale", "agent_windows", "min_ade", "min_fde", "nc"]
    )
    table.round({"min_ade": 4, "min_fde": 4}).to_csv(args.csv, index=False)
    print(table.to_string(index=False))


if __name__ == "__main__":
    main()
