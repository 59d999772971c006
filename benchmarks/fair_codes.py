"""The shipped goal variants under the fair protocol with each code (`evaluate.fair_code`): sample k decodes
goal k from a prior draw (or the DLow sampler's code k), or from the prior's mean.

Every shipped model that reads a goal is scored on its own validation windows with the goals of the profile's
shipped goal U-Net (`fftool.learning.fair_validation`, as `fftool models validate` scores them), beside the
constant-acceleration curves to the same goals (`benchmarks/goal_curves.py`, no network) and AgentFormer
(DLow), which reads no goal (its best epoch's validation, from its manifest). Reads no test window.

    fftool models install && fftool ingest -c pipelines/cpu.toml && fftool forces -c pipelines/cpu.toml
    fftool maps -c pipelines/cpu.toml && fftool sample-goals --benchmarks all -c pipelines/cpu.toml
    python benchmarks/fair_codes.py --benchmarks all --csv benchmarks/results/fair_codes_five.csv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import goal_curves  # beside this script
import pandas as pd
import torch

from fftool import zoo
from fftool.artifacts.store import ArtifactStore
from fftool.dataset.scenes import BENCHMARKS
from fftool.learning.fair_validation import fair_validation
from fftool.variants import reads_goal


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--benchmarks", default="all")
    parser.add_argument("--profile", default="cpu")
    parser.add_argument("--root", type=Path, default=Path("artifacts"))
    parser.add_argument("--csv", type=Path, required=True)
    args = parser.parse_args()
    benchmarks = BENCHMARKS if args.benchmarks == "all" else tuple(args.benchmarks.split(","))
    source, rows = ArtifactStore(args.root), []
    for benchmark in benchmarks:
        goals = zoo.shipped_goals(source, args.profile, benchmark)
        models = zoo.shipped(args.profile, [benchmark])
        cvaes = {m.variant: m.artifact for m in models if m.kind == "cvae"}
        for model in models:
            if model.kind == "dlow" and model.variant == "baseline":
                stats = model.artifact.manifest.stats
                best = next(r for r in stats["log"] if r["epoch"] == stats["best_epoch"])
                numbers = {"min_ade_m": best["val_min_ade@20_m"], "min_fde_m": best["val_min_fde@20_m"]}
                rows.append((benchmark, "baseline", model.artifact.id, "DLow sampler (reads no goal)", numbers))
            if model.variant is None or not reads_goal(model.variant):
                continue
            cvae = cvaes[model.variant]
            dlow = model.artifact if model.kind == "dlow" else None
            codes = ("prior",) if dlow else ("prior", "mean")
            for code in codes:
                found = fair_validation(source, goals, cvae, dlow, torch.device("cpu"), code)
                label = "DLow sampler" if dlow else {"prior": "prior draws", "mean": "prior mean"}[code]
                rows.append((benchmark, model.variant, model.artifact.id, label, found))
            if model.kind == "cvae" and model.variant == "goal":
                ade, fde, _ = goal_curves.score(source, goals, cvae)
                rows.append((benchmark, "curves", "", "goal curves (no network)", {"min_ade_m": ade, "min_fde_m": fde}))
        print(f"{benchmark}: {sum(r[0] == benchmark for r in rows)} rows", file=sys.stderr, flush=True)
    table = pd.DataFrame(
        [(b, v, m, s, round(n["min_ade_m"], 4), round(n["min_fde_m"], 4)) for b, v, m, s, n in rows],
        columns=["benchmark", "variant", "model", "sampling", "fair_min_ade_m", "fair_min_fde_m"],
    )
    table.to_csv(args.csv, index=False)
    print(table.to_string(index=False))


if __name__ == "__main__":
    main()
