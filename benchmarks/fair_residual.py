"""What a goal variant's decoder adds to the curve its output is a residual over, under the fair protocol.

dr and re output a residual over the constant-acceleration curve to their goal (`cvae.output =
"goal_residual"`) and decode each of the goal module's K goals from the prior's mean code. This scores each
shipped model of that kind with the decoder's output head scaled by each factor α (`cvae_model.scale_output`):
1 is the model as shipped, 0 the curve alone (no network). The goals are those of the profile's shipped goal
U-Net, the code the one its profile decodes goals with.

- `--part val` (the default) scores each model as `fftool models validate` does (its own validation windows):
  minADE / minFDE. Reads no test window.
- `--part test` runs the `evaluate` stage's own scoring (`stages.evaluate.sample_and_score`: every test
  agent-window) so that minADE, minFDE and the collisions (NC) compare with the reports' rows, which α = 1
  reproduces; an ablation read after every choice was made.

    fftool models install && fftool ingest -c pipelines/cpu.toml && fftool forces -c pipelines/cpu.toml
    fftool maps -c pipelines/cpu.toml && fftool sample-goals --benchmarks all -c pipelines/cpu.toml
    python benchmarks/fair_residual.py --scales 1,0.5,0 --csv benchmarks/results/fair_residual_five.csv
    python benchmarks/fair_residual.py --part test --scales 1,0 --csv benchmarks/results/fair_residual_test.csv
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

import pandas as pd
import torch

from fftool import zoo
from fftool.artifacts.store import Artifact, ArtifactStore
from fftool.config import EvaluateConfig, FairCode, predictor_config, variant_section
from fftool.dataset.scenes import BENCHMARKS
from fftool.learning.cvae_model import load_model, scale_output
from fftool.learning.fair_validation import fair_validation
from fftool.stages import evaluate

_COLUMNS = {
    "val": ["code", "residual_scale", "val_windows", "fair_min_ade_m", "fair_min_fde_m"],
    "test": ["residual_scale", "agent_windows", "min_ade", "min_fde", "nc"],
}


def _validation(store: ArtifactStore, goals: Artifact, cvae: Artifact, code: FairCode, scale: float) -> list[Any]:
    found = fair_validation(store, goals, cvae, None, torch.device("cpu"), code, None, scale)
    return [found["code"], scale, found["windows"], round(found["min_ade_m"], 4), round(found["min_fde_m"], 4)]


def _test(store: ArtifactStore, goals: Artifact, cvae: Artifact, cfg: EvaluateConfig, scale: float) -> list[Any]:
    evaluate.load_model = lambda artifact, device: scale_output(load_model(artifact, device), scale)
    windows, forces = (store.lookup(kind, cvae.manifest.sources[kind]) for kind in ("windows", "forces"))
    benchmark = str(cvae.manifest.stats["benchmark"])
    with tempfile.TemporaryDirectory() as out:
        found = evaluate.sample_and_score(cfg, benchmark, windows, forces, cvae, goals, Path(out), torch.device("cpu"))
    nc = found["nc"]["best_ade"]["ordered"]
    return [scale, found["agent_windows"], round(found["min_ade"], 4), round(found["min_fde"], 4), nc]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--benchmarks", default="all")
    parser.add_argument("--part", choices=("val", "test"), default="val")
    parser.add_argument("--profile", default="cpu")
    parser.add_argument("--root", type=Path, default=Path("artifacts"))
    parser.add_argument("--scales", default="1,0.5,0", help="factors α of the decoder's output head (1: as shipped)")
    parser.add_argument("--csv", type=Path, required=True)
    args = parser.parse_args()
    benchmarks = BENCHMARKS if args.benchmarks == "all" else tuple(args.benchmarks.split(","))
    scales = [float(s) for s in args.scales.split(",")]
    cfg, store, rows = zoo.profile_config(args.profile), ArtifactStore(args.root), []
    for benchmark in benchmarks:
        goals = zoo.shipped_goals(store, args.profile, benchmark)
        for model in zoo.shipped(args.profile, [benchmark]):
            if model.kind != "cvae" or model.artifact.manifest.params.get("output") != "goal_residual":
                continue
            evaluate_cfg = variant_section(predictor_config(cfg, model.variant), "evaluate")
            assert isinstance(evaluate_cfg, EvaluateConfig)
            for scale in scales:
                if args.part == "val":
                    found = _validation(store, goals, model.artifact, evaluate_cfg.fair_code, scale)
                else:
                    found = _test(store, goals, model.artifact, evaluate_cfg, scale)
                rows.append([benchmark, model.variant, model.artifact.id, *found])
                print(*rows[-1], file=sys.stderr, flush=True)
    table = pd.DataFrame(rows, columns=["benchmark", "variant", "model", *_COLUMNS[args.part]])
    table.to_csv(args.csv, index=False)
    print(table.to_string(index=False))


if __name__ == "__main__":
    main()
