"""Which path to a goal: minADE / minFDE of the goal module's K goals with no network after them, sample k being a
curve from the last observed position to goal k, for several curve shapes, under the fair protocol, on validation
windows. Every curve reaches its goal at the last step, so minFDE is the same for all; minADE says which path the
way there should follow.

- "acceleration": the constant-acceleration curve that leaves with the last observed step (the curve
  `cvae.output = "goal_residual"` is a residual over, `forceformer.output_base`);
- "relaxation τ": the path under Helbing's driving force alone, F = (w − v) / τ with a constant desired step w:
  the step relaxes from the last observed one toward w by exp(−dt / τ) per step, w chosen so the path reaches the
  goal at the last step (the path `cvae.output = "relaxation_residual"` is a residual over, with τ / dt time
  steps); τ = 0 is the straight line to the goal at constant speed, τ → ∞ tends to a
  constant-acceleration curve.

With `--place P --goal-store S`, only the val windows of place P, with the goals of a goal U-Net that never saw P
(a `goal_levers.py --holdout --place P` store); without, the whole val part and the shipped goal U-Net. Reads no
test window.

    python benchmarks/goal_curve_shapes.py --root /tmp/cpu/artifacts --benchmark zara1 --place hotel \\
        --goal-store /tmp/fftool_goal_levers/recipe_s0@holdout-hotel-in-scene \\
        --out benchmarks/results/goal_curve_shapes.csv
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from goal_curves import goal_curves
from goal_hedge import module_goals, place_windows
from goal_levers import PLACES, _append, _trained

from fftool import pipeline, zoo
from fftool.artifacts.store import ArtifactStore
from fftool.config import EvaluateConfig, predictor_config, variant_section
from fftool.learning.batches import load_scene_set
from fftool.science.metrics import ade_fde

TAUS_S = (0.0, 0.25, 0.5, 1.0, 2.0, 4.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--root", type=Path, required=True, help="artifact root with the profile's data stages")
    parser.add_argument("--profile", default="cpu")
    parser.add_argument("--benchmark", required=True)
    parser.add_argument("--place", choices=list(PLACES), help="score this place's val windows only")
    parser.add_argument("--goal-store", type=Path, help="with --place: the goal_levers store of a module without it")
    parser.add_argument("--taus", default=",".join(map(str, TAUS_S)), help="relaxation times τ (s), comma-separated")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    if bool(args.place) != bool(args.goal_store):
        parser.error("--place and --goal-store go together")
    torch.set_num_threads(1)
    cfg, benchmark = zoo.profile_config(args.profile), args.benchmark
    built = pipeline.run(cfg, ArtifactStore(args.root), ["forces", "maps"], benchmark=benchmark)
    windows, maps = built["windows"], built["maps"]
    shipped = {(m.kind, m.variant): m.artifact for m in zoo.shipped(args.profile, [benchmark])}
    goal = _trained(ArtifactStore(args.goal_store), benchmark) if args.goal_store else shipped["goal", None]
    evaluate = variant_section(predictor_config(cfg, "dr"), "evaluate")
    assert isinstance(evaluate, EvaluateConfig)
    scenes = load_scene_set(windows, None, benchmark, "val", reads=())
    obs_len, dt = int(windows.manifest.stats["obs_len"]), cfg.ingest.dt_s
    goals = torch.as_tensor(module_goals(cfg, benchmark, goal, windows, maps, evaluate.k, scenes))  # (M, K, 2)
    plan = scenes.plan(
        place_windows(scenes, args.place), evaluate.batch_windows, evaluate.max_agent_pairs, np.random.default_rng(0)
    )
    taus = [float(v) for v in args.taus.split(",")]
    curves = {"acceleration": ("goal_residual", 0.0)}  # name -> cvae.output, relaxation_steps
    curves |= {f"relaxation {tau:g} s": ("relaxation_residual", tau / dt) for tau in taus}
    sums = {name: np.zeros(2) for name in curves}
    count = 0
    for members in plan:
        batch = scenes.batch(members)
        rows = batch.row.numpy()
        positions = np.where(rows >= 0, np.searchsorted(scenes.data.row, rows), 0)
        goal_k = goals[torch.as_tensor(positions)].transpose(1, 2)  # (B, K, A, 2)
        mask = batch.agent_mask
        for name, (output, relaxation_steps) in curves.items():
            path = goal_curves(batch.xy, goal_k, obs_len, output, relaxation_steps)
            ade, fde = ade_fde(path, batch.xy[:, :, obs_len:])  # (B, K, A)
            sums[name] += [float((ade.min(1).values * mask).sum()), float((fde.min(1).values * mask).sum())]
        count += int(mask.sum())
    goal_name = f"{goal.id}@{args.goal_store.name}" if args.goal_store else f"{goal.id} (shipped)"
    records = [
        {
            "benchmark": benchmark,
            "place": args.place or "val part",
            "goal_unet": goal_name,
            "goal_seed": goal.manifest.params["seed"],
            "curve": name,
            "agent_windows": count,
            "min_ade_m": round(sums[name][0] / count, 4),
            "min_fde_m": round(sums[name][1] / count, 4),
        }
        for name in curves
    ]
    for record in records:
        print(record, flush=True)
    _append(args.out, records)


if __name__ == "__main__":
    main()
