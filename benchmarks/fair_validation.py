"""Validation minADE / minFDE of trained CVAEs under the fair protocol: sample k decodes the goal module's goal k.

The number a goal variant's best epoch is chosen by when it trains with `goal_training.source = "module"`,
computed here for any CVAE (for instance one trained with true goals) on the same validation windows (the
model's own fixed subset) and the same goals, so the two can be compared. Reads no test window.

    python benchmarks/fair_validation.py --root R --goals goals/<id> cvae/<id> [cvae/<id> ...]
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
import torch

from fftool.api import find_artifact
from fftool.learning.batches import load_scene_set
from fftool.learning.cvae_model import load_model, val_windows
from fftool.learning.features import TRAINING_READS
from fftool.learning.sampling import fair_min_ade_fde, load_sampled_goals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("models", nargs="+", help="CVAE artifact ids (cvae/<id>)")
    parser.add_argument("--goals", required=True, help="the goals artifact (goals/<id>) of the same benchmark")
    parser.add_argument("--root", type=Path, default=Path("artifacts"))
    parser.add_argument("--k", type=int, default=20)
    args = parser.parse_args()
    device = torch.device("cpu")
    writer = csv.writer(sys.stdout)
    writer.writerow(["cvae", "variant", "benchmark", "val_windows", "fair_min_ade_m", "fair_min_fde_m"])
    store, goals = find_artifact(args.goals, "goals", args.root)
    for ref in args.models:
        _, cvae = find_artifact(ref, "cvae", args.root)
        trained = load_model(cvae, device)
        benchmark, cfg = cvae.manifest.stats["benchmark"], trained.config
        windows = store.lookup("windows", cvae.manifest.sources["windows"])
        forces_key = next((key for key in cvae.manifest.inputs if key.startswith("forces")), None)
        forces = store.lookup("forces", cvae.manifest.sources["forces"]) if forces_key else None
        val = load_scene_set(windows, forces, benchmark, "val", reads=TRAINING_READS[cfg.variant])
        sampled = np.asarray(load_sampled_goals(goals, val, benchmark, "val"))
        obs_len = int(windows.manifest.stats["obs_len"])
        ade, fde = fair_min_ade_fde(trained, val, val_windows(val, cfg), sampled, obs_len, args.k, cfg.seed)
        writer.writerow([cvae.id, cfg.variant, benchmark, len(val_windows(val, cfg)), f"{ade:.4f}", f"{fde:.4f}"])


if __name__ == "__main__":
    main()
