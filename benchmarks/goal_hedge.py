"""Goal variants hedged with AgentFormer: m of the K samples from the baseline's DLow codes 1..m, the other K − m
from the goal variant decoding K − m goals of the goal module, under the fair protocol, on validation windows.
The m are the DLow sampler's codes 1..m (pick "first"), or the m of its K end points that farthest-point sampling
adds to the variant's (pick "spread"): both from the same samples, a row each.

Scores the shipped cpu models of one benchmark on its val-part windows. With `--place P --goal-store S`, only
the windows of place P, with the goals of the benchmark's goal U-Net in S (a `goal_levers.py --holdout --place P`
store: a module that never saw P); without, the whole val part and the shipped goal U-Net. Reads no test window.
Appends two CSV rows per m, one per pick (m = 0: the variant as shipped; m = K: AgentFormer alone). `--code prior`
decodes each goal from a draw of the prior (or the variant's DLow sampler's code) instead of the profile's code;
`--goals agentformer` gives the variant the end points of AgentFormer's K samples as its K goals (m = 0); `--cvae`
scores another CVAE of the variant (one retrained with a lever) in the shipped one's place.

    python benchmarks/goal_hedge.py --root /tmp/cpu/artifacts --benchmark zara1 --variant dr --place hotel \\
        --goal-store /tmp/fftool_goal_levers/recipe_s0@holdout-hotel-in-scene --out benchmarks/results/goal_hedge.csv

The root needs the profile's windows, forces and maps (`fftool reproduce pipelines/cpu.toml --to maps` or any
run that built them). docs/experiments/goal-hedge.md has the rule and the results.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import torch
from goal_levers import PLACES, _append, _trained

from fftool import pipeline, zoo
from fftool.api import find_artifact
from fftool.artifacts.schema import GOALS_FILE, GOALS_INDEX_FILE
from fftool.artifacts.store import Artifact, ArtifactStore
from fftool.config import EvaluateConfig, PipelineConfig, predictor_config, variant_section
from fftool.learning.batches import SceneSet, load_scene_set
from fftool.learning.cvae_model import load_model
from fftool.learning.dlow_model import load_sampler
from fftool.learning.sampling import Predictor, aligned_goals, collect, sample_batches
from fftool.science.metrics import ade_fde
from fftool.stages import goals as goals_stage

HEDGES = (0, 2, 4, 6, 10)


def per_sample(
    predictor: Predictor, scenes: SceneSet, plan: list[np.ndarray], obs_len: int, device: torch.device
) -> dict[str, np.ndarray]:
    """Every real agent-window's ADE and FDE (N, K) and end point (N, K, 2) of each of the predictor's K samples,
    and its row (N,), in the scene set's row order."""

    def fields(batch, goals, futures):  # type: ignore[no-untyped-def]
        ade, fde = ade_fde(futures, batch.xy[:, :, obs_len:])  # (B, K, A)
        return {"ade": ade.transpose(1, 2), "fde": fde.transpose(1, 2), "end": futures[..., -1, :].transpose(1, 2)}

    return collect(sample_batches(predictor, scenes, plan, predictor.goals, device), fields)


def spread_picks(variant_ends: np.ndarray, baseline_ends: np.ndarray, m: int) -> np.ndarray:
    """(N, m) baseline samples chosen by farthest-point sampling: each pick is the baseline end point farthest
    from every end point kept so far (the variant's K − m, then the earlier picks). No true future is read."""
    rows, picks = np.arange(len(baseline_ends)), []
    gap = np.full(baseline_ends.shape[:2], np.inf)
    if variant_ends.shape[1]:
        gap = np.linalg.norm(baseline_ends[:, :, None] - variant_ends[:, None], axis=-1).min(-1)
    for _ in range(m):
        pick = gap.argmax(1)
        picks.append(pick)
        gap = np.minimum(gap, np.linalg.norm(baseline_ends - baseline_ends[rows, pick][:, None], axis=-1))
        gap[rows, pick] = -1.0  # never picked twice, even where every end point left coincides with a kept one
    return np.stack(picks, 1) if picks else np.zeros((len(rows), 0), dtype=np.int64)


def hedged_min(goal_errors: np.ndarray, baseline_errors: np.ndarray, picks: np.ndarray) -> float:
    """Mean over agent-windows of the min over the variant's K − m samples and the baseline's picked m (N, m)."""
    chosen = np.take_along_axis(baseline_errors, picks, 1)
    return float(np.concatenate([goal_errors, chosen], 1).min(1).mean())


def module_goals(
    cfg: PipelineConfig, benchmark: str, goal: Artifact, windows: Artifact, maps: Artifact, k: int, scenes: SceneSet
) -> np.ndarray:
    """(M, k, 2) goals the goal U-Net `goal` draws for the val part (the profile's sampling, k goals), aligned
    with the scene set's agent-windows."""
    sampling = cfg.goals.model_copy(update={"k": k, "parts": ("val",)})
    with tempfile.TemporaryDirectory() as out:
        goals_stage.sample(sampling, benchmark, goal, windows, maps, Path(out), torch.device("cpu"))
        return np.array(aligned_goals(Path(out) / GOALS_INDEX_FILE, Path(out) / GOALS_FILE, scenes, benchmark, "val"))


def place_windows(scenes: SceneSet, place: str | None) -> np.ndarray:
    """The scene set's windows whose agents come from `place`'s files (every window without a place)."""
    firsts = scenes.data.source[scenes.window_start[:-1]]
    return np.flatnonzero(np.isin(firsts, PLACES[place])) if place else np.arange(scenes.windows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--root", type=Path, required=True, help="artifact root with the profile's data stages")
    parser.add_argument("--profile", default="cpu")
    parser.add_argument("--benchmark", required=True)
    parser.add_argument("--variant", default="dr", choices=("goal", "dr", "re"))
    parser.add_argument("--place", choices=list(PLACES), help="score this place's val windows only")
    parser.add_argument("--goal-store", type=Path, help="with --place: the goal_levers store of a module without it")
    parser.add_argument(
        "--code", choices=("mean", "prior"), help="the code each goal decodes with (default: the profile's)"
    )
    parser.add_argument(
        "--goals",
        choices=("module", "agentformer"),
        default="module",
        help="the K goals: the goal U-Net's, or the end points of AgentFormer's K samples (then m = 0 only)",
    )
    parser.add_argument("--cvae", help="the variant's CVAE (cvae/<id> in --root) instead of the shipped one")
    parser.add_argument("--hedges", default=",".join(map(str, HEDGES)), help="values of m, comma-separated")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    if args.goals == "module" and bool(args.place) != bool(args.goal_store):
        parser.error("--place and --goal-store go together")
    torch.set_num_threads(1)
    device, benchmark = torch.device("cpu"), args.benchmark
    cfg = zoo.profile_config(args.profile)
    store = ArtifactStore(args.root)
    built = pipeline.run(cfg, store, ["forces", "maps"], benchmark=benchmark)
    windows, forces, maps = built["windows"], built["forces"], built["maps"]
    shipped = {(m.kind, m.variant): m.artifact for m in zoo.shipped(args.profile, [benchmark])}
    goal = _trained(ArtifactStore(args.goal_store), benchmark) if args.goal_store else shipped["goal", None]
    hedges = {int(v) for v in args.hedges.split(",")}
    if args.goals == "agentformer":
        hedges, goal_name, goal_seed = {0}, "AgentFormer's end points", None
    else:
        goal_name = f"{goal.id}@{args.goal_store.name}" if args.goal_store else f"{goal.id} (shipped)"
        goal_seed = goal.manifest.params["seed"]
    scenes = load_scene_set(windows, forces, benchmark, "val")
    obs_len = int(windows.manifest.stats["obs_len"])
    pred_len = int(windows.manifest.stats["pred_len"])
    chosen = place_windows(scenes, args.place)
    base_cfg = variant_section(predictor_config(cfg, "baseline"), "evaluate")
    variant_cfg = variant_section(predictor_config(cfg, args.variant), "evaluate")
    assert isinstance(base_cfg, EvaluateConfig) and isinstance(variant_cfg, EvaluateConfig)
    variant_cfg = variant_cfg.model_copy(update={"fair_code": args.code or variant_cfg.fair_code})
    k = base_cfg.k
    plan = scenes.plan(chosen, base_cfg.batch_windows, base_cfg.max_agent_pairs, np.random.default_rng(base_cfg.seed))
    baseline = Predictor(
        base_cfg,
        load_model(shipped["cvae", "baseline"], device),
        None,
        obs_len,
        pred_len,
        device,
        load_sampler(shipped["dlow", "baseline"], device),
    )
    base = per_sample(baseline, scenes, plan, obs_len, device)
    cvae = find_artifact(args.cvae, "cvae", args.root)[1] if args.cvae else shipped["cvae", args.variant]
    trained = load_model(cvae, device)
    dlow = shipped.get(("dlow", args.variant))
    sampler = load_sampler(dlow, device) if dlow is not None and variant_cfg.fair_code == "prior" else None
    records = []
    for m in sorted(hedges | {k}):
        if m < k:
            if args.goals == "agentformer":  # sample k of an agent-window heads to AgentFormer's end point k
                drawn = np.zeros((len(scenes.data), k, 2), dtype=np.float32)
                drawn[np.searchsorted(scenes.data.row, base["row"])] = base["end"]
            else:
                drawn = module_goals(cfg, benchmark, goal, windows, maps, k - m, scenes)
            evaluate = variant_cfg.model_copy(update={"k": k - m})
            predictor = Predictor(evaluate, trained, drawn, obs_len, pred_len, device, sampler)
            own = per_sample(predictor, scenes, plan, obs_len, device)
            assert np.array_equal(own["row"], base["row"]), "the two predictors scored different agent-windows"
        else:
            own = {name: np.zeros((len(base["row"]), 0, *base[name].shape[2:])) for name in ("ade", "fde", "end")}
        first = np.broadcast_to(np.arange(m), (len(base["row"]), m))
        for pick, picks in (("first", first), ("spread", spread_picks(own["end"], base["end"], m))):
            records.append(
                {
                    "benchmark": benchmark,
                    "variant": args.variant,
                    "cvae": cvae.id if args.cvae else "shipped",
                    "place": args.place or "val part",
                    "goals": args.goals,
                    "goal_unet": goal_name,
                    "goal_seed": goal_seed,
                    "code": "dlow" if sampler is not None else variant_cfg.fair_code,
                    "m": m,
                    "pick": pick,
                    "agent_windows": len(base["row"]),
                    "min_ade_m": round(hedged_min(own["ade"], base["ade"], picks), 4),
                    "min_fde_m": round(hedged_min(own["fde"], base["fde"], picks), 4),
                }
            )
            print(records[-1], flush=True)
    _append(args.out, records)


if __name__ == "__main__":
    main()
