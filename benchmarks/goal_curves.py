"""Validation minADE / minFDE of the goal module's goals with no network after them: sample k is the
constant-acceleration curve that leaves the last observed position with the last observed step and reaches
goal k at the last predicted step (the path `cvae.output = "goal_residual"` is a residual over).

A reference for the goal variants under the fair protocol: scored on the same validation windows (a CVAE's
own fixed subset) with the same goals as `benchmarks/fair_validation.py`. Reads no test window.

    python benchmarks/goal_curves.py --root R --goals goals/<id> cvae/<id>
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
import torch

from fftool.api import find_artifact
from fftool.artifacts.store import Artifact, ArtifactStore
from fftool.learning.batches import load_scene_set
from fftool.learning.cvae_model import load_model, val_windows
from fftool.learning.sampling import load_sampled_goals
from fftool.models.forceformer import output_base
from fftool.science.metrics import ade_fde


def goal_curves(
    xy: torch.Tensor, goals: torch.Tensor, obs_len: int, output: str = "goal_residual", relaxation_steps: float = 5.0
) -> torch.Tensor:
    """(B, K, A, T, 2) curves from paths xy (B, A, obs_len + T, 2) to goals (B, K, A, 2), world metres: the path a
    decoder with `cvae.output = output` is a residual over (`forceformer.output_base`)."""
    last = xy[:, None, :, obs_len - 1]
    step = last - xy[:, None, :, obs_len - 2]
    steps = xy.shape[2] - obs_len
    ahead = [output_base(output, s, steps, last, step, goals, relaxation_steps) for s in range(steps)]
    return last[..., None, :] + torch.stack(ahead, -2)


def score(store: ArtifactStore, goals: Artifact, cvae: Artifact) -> tuple[float, float, int]:
    """Fair minADE / minFDE (m) of the goal curves on `cvae`'s validation windows, and the number of windows."""
    cfg, benchmark = load_model(cvae, torch.device("cpu")).config, str(cvae.manifest.stats["benchmark"])
    windows = store.lookup("windows", cvae.manifest.sources["windows"])
    obs_len = int(windows.manifest.stats["obs_len"])
    val = load_scene_set(windows, None, benchmark, "val", reads=())
    sampled = torch.as_tensor(np.asarray(load_sampled_goals(goals, val, benchmark, "val")))  # (M, K, 2)
    subset = val_windows(val, cfg)
    ade, fde, count = 0.0, 0.0, 0
    for members in val.plan(subset, cfg.batch_windows, cfg.max_agent_pairs, np.random.default_rng(0)):
        batch = val.batch(members)
        rows = batch.row.numpy()
        positions = np.where(rows >= 0, np.searchsorted(val.data.row, rows), 0)
        goals_k = sampled[torch.as_tensor(positions)].transpose(1, 2)  # (B, K, A, 2)
        sample_ade, sample_fde = ade_fde(goal_curves(batch.xy, goals_k, obs_len), batch.xy[:, :, obs_len:])
        mask = batch.agent_mask
        ade += float((sample_ade.min(1).values * mask).sum())
        fde += float((sample_fde.min(1).values * mask).sum())
        count += int(mask.sum())
    return ade / count, fde / count, len(subset)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", help="the CVAE (cvae/<id>) whose validation windows are scored")
    parser.add_argument("--goals", required=True, help="the goals artifact (goals/<id>) of the same benchmark")
    parser.add_argument("--root", type=Path, default=Path("artifacts"))
    args = parser.parse_args()
    store, goals = find_artifact(args.goals, "goals", args.root)
    cvae = find_artifact(args.model, "cvae", args.root)[1]
    ade, fde, windows = score(store, goals, cvae)
    writer = csv.writer(sys.stdout)
    writer.writerow(["model", "benchmark", "val_windows", "fair_min_ade_m", "fair_min_fde_m"])
    writer.writerow(["goal curves", cvae.manifest.stats["benchmark"], windows, f"{ade:.4f}", f"{fde:.4f}"])


if __name__ == "__main__":
    main()
