"""The goal module's levers measured on validation: each alone against the shipped recipe, and together.

Every lever trains the goal U-Net of each benchmark with the profile's recipe plus the lever's `--set`
overrides (in its own artifact root), then scores the best epoch on the benchmark's **whole val part**:
goal-FDE@20 (TTST, the profile's sampling) and FDE@1 for the mode found three ways (argmax, and the local
softargmax over 3² and 5² cells). No test window is read. Appends one CSV row per (lever, benchmark, mode).

    python benchmarks/goal_levers.py --lever before --benchmarks all --out benchmarks/results/goal_levers.csv

With `--holdout`, the validation is a place held out of training instead of the val part: benchmark B's
goal U-Net trains on B's train part without the windows of the place HOLDOUT[B] (never B's test scene), picks
its best epoch on that place's windows (B's train and val parts), and is scored on all of them. That is the
leave-one-out situation the test meets (a scene the module never saw), measured without a test window.

With `--holdout --place P`, B holds out P, any other place it trains on, instead of HOLDOUT[B]; the rows' lever
column ends with `place=P`.

With `--holdout --select-in-scene`, the goal U-Net still trains without that place but chooses its best epoch as the
shipped modules do, on B's val part (without the place's windows); only the scoring reads the place. `--curves FILE`
appends the trained model's per-epoch validation (what chose its best epoch) to FILE.

With `--ensemble L2 --ensemble L3`, the lever's trained models are scored together with those of levers L2 and L3
(trained first, with the same --holdout options): each cell's probability is the mean of the members', then TTST
samples it as it samples one module's.

With `--blank-maps`, a lever's trained models are scored with every map channel zero, as `fftool predict` and the
API run them on a user's tracks (lever "shipped": the shipped goal U-Nets, installed into its store first).

One lever per process. "before" puts the crop centre back on a cell corner (patch `corner`) and the mode
back on the argmax cell; "centre" only the second; the other levers change one thing from "before".
"profile" is the profile file as it is (the shipped recipe), "profile_uni_map" the same with univ's map for
uni_examples (patch `uni_map`); "place_balance_0.5" draws each epoch's windows with a place's share ∝ n^(1 − β)
(patch `place_balance_<β>`). docs/experiments/goal-levers.md has the results and the rule.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import os
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import tomllib
import torch

from fftool import pipeline
from fftool.artifacts.schema import TRACKS_FILE, VERSIONS
from fftool.artifacts.store import Artifact, ArtifactStore
from fftool.config import GoalsConfig, load_config
from fftool.dataset import scenes
from fftool.dataset.scenes import BENCHMARKS
from fftool.learning import batches, devices, goal_model, protocols
from fftool.learning.batches import AgentWindows, load_agent_windows
from fftool.learning.scene_prior import goal_scene_index, load_goal_scenes, source_place
from fftool.learning.training import generator
from fftool.pipeline import Runtime
from fftool.science import heatmaps

# name -> (--set overrides on the profile, patches that undo or add a geometry choice). The levers were chosen
# against the profile as it was before (mode: the argmax cell), which the first four restore.
_ARGMAX = "goals.mode_radius_cells=0"
LEVERS: dict[str, tuple[list[str], list[str]]] = {
    "before": ([_ARGMAX], ["corner"]),
    "centre": ([_ARGMAX], []),
    "target_sigma_0.5": ([_ARGMAX, "goal.target_sigma_cells=0.5"], ["corner"]),
    "reversal_0.5": ([_ARGMAX, "goal.time_reversal=0.5"], ["corner"]),
    "profile": ([], []),  # the profile as it is: the chosen recipe
    "profile_uni_map": ([], ["uni_map"]),
    "profile_rerun": ([], []),  # the profile again with today's code: the reference the later levers meet
    # The shipped goal U-Nets: `fftool models install --benchmarks all --root <root>/shipped` first (the profile's
    # fingerprints, so nothing trains); with --blank-maps, scored as `fftool predict` runs them.
    "shipped": ([], []),
    # The recipe shipped before map dropout (48 epochs, every crop with its map).
    "before_map_dropout": (["goal.map_dropout=0"], []),
    # Capacity, against "profile": 1.5× the widths (2.25× the multiply-adds), and three supervised output maps.
    "wide_1.5": (["goal.widths=[12, 24, 24, 48]"], []),
    "supervised_3": (["goal.supervised_steps=3"], []),
    # Resolution: 0.25 m cells in a 64-cell crop (±8 m; 1.8× the multiply-adds); the mode still over 5 × 5 cells.
    "cells_0.25": (["goal.resolution_m=0.25", "goal.crop_cells=64"], []),
    # Steps, against "profile": 4× the training windows (16 epochs of 9,216), the same cosine stretched.
    "steps_4x": (["goal.epochs=16", "goal.max_train=9216"], []),
    # Input, against "profile": the training part's occupancy of the same place as one more map channel.
    "scene_prior": (['goal.scene_prior="occupancy"'], []),
    # Against the shipped recipe (16 epochs): 3× its steps, which channels-last training fits in 30 minutes.
    "steps_3x_shipped": (["goal.epochs=48"], []),
    # Beyond the CPU budget (trained on a GPU; each one's CPU cost is estimated from its steps): what more
    # training and Goal-SAR's own widths buy, against "profile" trained on the same GPU.
    "steps_4x_more": (["goal.epochs=64"], []),
    "steps_16x_more": (["goal.epochs=256"], []),
    "goalsar_widths": (["goal.widths=[32, 32, 64, 64, 64]"], []),
    "goalsar_widths_steps_4x": (["goal.widths=[32, 32, 64, 64, 64]", "goal.epochs=64"], []),
    # No network: the constant-velocity reference (CV@K and CV@1 as sample-goals draws them) on the same windows.
    "constant_velocity": ([], []),
    # Against "before_map_dropout": the scene map withheld from a share of the training windows (they see the
    # all-zero scene, as `fftool predict` and the API give the module), so it also serves data without a map.
    "map_dropout_0.5": (["goal.map_dropout=0.5"], []),
    "map_dropout_0.25": (["goal.map_dropout=0.25"], []),
    "map_dropout_1": (["goal.map_dropout=1"], []),
    # Against "profile" (48 epochs), on a held-out place with the best epoch chosen on the val part: a shorter
    # cosine (with "steps_4x", 16 epochs).
    "epochs_8": (["goal.epochs=8"], []),
    # Members of an ensemble with "epochs_8" (`--ensemble`): the same recipe from other seeds.
    "epochs_8_seed1": (["goal.epochs=8", "goal.seed=1"], []),
    "epochs_8_seed2": (["goal.epochs=8", "goal.seed=2"], []),
    "recipe_8_argmax": ([], []),  # the cpu recipe as shipped (8 epochs, best epoch under the argmax mode)
    # Each epoch's windows drawn with replacement, a place's share of them ∝ its training windows^(1 − β), instead
    # of the shares the files give (univ's square holds about 70 % of every other benchmark's training windows).
    "place_balance_0.5": ([], ["place_balance_0.5"]),
    "weight_decay_0.1": (["goal.weight_decay=0.1"], []),  # AdamW's decay 10× the recipe's 0.01
    "weight_decay_0": (["goal.weight_decay=0"], []),
    "epochs_4": (["goal.epochs=4"], []),  # half the cpu recipe's steps, the same cosine compressed
    # The window's other walkers and their CV goals as two input channels (goal.neighbour_channels).
    "neighbours": (["goal.neighbour_channels=true"], []),
    "recipe_8_argmax_seed1": (["goal.seed=1"], []),  # the pair again from another seed: how large the margin is
    "neighbours_seed1": (["goal.neighbour_channels=true", "goal.seed=1"], []),
}
# Three trainings per arm, all on one machine in one batch: the cpu recipe, and the recipe with time reversal
# (p = 0.5), the target's σ at half a cell or walking speeds scaled (goal.speed_scale), from seeds 0, 1 and 2.
for _seed in range(3):
    LEVERS[f"recipe_s{_seed}"] = ([f"goal.seed={_seed}"], [])
    LEVERS[f"reversal_s{_seed}"] = (["goal.time_reversal=0.5", f"goal.seed={_seed}"], [])
    LEVERS[f"target_sigma_s{_seed}"] = (["goal.target_sigma_cells=0.5", f"goal.seed={_seed}"], [])
    LEVERS[f"speed_s{_seed}"] = (["goal.speed_scale=1.25", f"goal.seed={_seed}"], [])  # walkers 0.8 to 1.25× as fast
MODE_RADII = (0, 1, 2)

# --holdout: the place each benchmark's validation holds out of its training part: one of its own training places,
# never its test scene, whose removal leaves most of the training windows (univ's place is half of every other
# benchmark's, and eth's 300 windows are too few to score). univ's place includes uni_examples, zara's all three files.
PLACES: dict[str, tuple[str, ...]] = {
    "eth": ("biwi_eth",),
    "hotel": ("biwi_hotel",),
    "univ": ("students001", "students003", "uni_examples"),
    "zara": ("crowds_zara01", "crowds_zara02", "crowds_zara03"),
}
HOLDOUT: dict[str, str] = {"eth": "hotel", "hotel": "zara", "univ": "hotel", "zara1": "hotel", "zara2": "hotel"}


def _patch(name: str) -> None:
    if name == "corner":
        heatmaps.world_to_cells.__code__ = _corner_world_to_cells.__code__
        heatmaps.cells_to_world.__code__ = _corner_cells_to_world.__code__
    elif name == "uni_map":
        scenes.SOURCE_SCENE["uni_examples"] = "univ"
    elif name.startswith("place_balance_"):
        _balance_places(float(name.removeprefix("place_balance_")))
    else:
        raise SystemExit(f"unknown patch {name!r}")


def place_weights(places: np.ndarray, beta: float) -> np.ndarray:
    """Each window's draw weight n^(−β), n the windows of its place: a place's share of the draws is ∝ n^(1 − β)."""
    _, inverse, counts = np.unique(places, return_inverse=True, return_counts=True)
    return counts[inverse].astype(np.float64) ** -beta


def _balance_places(beta: float) -> None:
    """Make the goal stage draw each epoch's windows with replacement, window i with weight n_place(i)^(−β), so that
    a place's share of the draws is ∝ n_place^(1 − β) (β = 0: the files' shares, β = 1: every place alike). A
    place is `scene_prior.source_place` (zara's three files are one place; uni_examples is univ's square)."""
    import fftool.stages.goal as goal_stage

    original = goal_stage._trainer

    def trainer(cfg, goals_cfg, benchmark, windows, maps, device):  # type: ignore[no-untyped-def]
        made = original(cfg, goals_cfg, benchmark, windows, maps, device)
        train = goal_stage.load_agent_windows(windows, benchmark, "train", stride=cfg.train_stride)
        sources, inverse = np.unique(train.source, return_inverse=True)
        places = np.array([source_place(source) or source for source in sources])[inverse]
        weights = torch.as_tensor(place_weights(places, beta))
        shares = {str(p): round(float(weights[places == p].sum() / weights.sum()), 3) for p in np.unique(places)}
        print(f"place shares of the draws (beta {beta}): {shares}", flush=True)
        made._epoch_windows = lambda gen: torch.multinomial(weights, made.per_epoch, replacement=True, generator=gen)
        return made

    goal_stage._trainer = trainer


def _hold_out(place: str, select_in_scene: bool = False) -> None:
    """Make the goal stage (and this script's scoring) read B's train part without `place`, and `place`'s windows
    of B's train and val parts as the validation part. With `select_in_scene`, the goal stage chooses its best
    epoch as the shipped modules do, on B's val part (without `place`'s windows), and only the scoring reads
    `place`."""
    original, sources = batches.load_agent_windows, PLACES[place]

    def without(windows: Artifact, benchmark: str, part: str, stride: int = 1) -> AgentWindows:
        if part == "test":
            raise SystemExit("--holdout reads no test part")
        data = original(windows, benchmark, part, stride)
        return data.subset(np.flatnonzero(~np.isin(data.source, sources)))

    def load(windows: Artifact, benchmark: str, part: str, stride: int = 1) -> AgentWindows:
        if part == "train":
            return without(windows, benchmark, "train", stride)
        if part != "val":
            raise SystemExit(f"--holdout reads no {part} part")
        held = [original(windows, benchmark, p, stride) for p in ("train", "val")]
        held = [w.subset(np.flatnonzero(np.isin(w.source, sources))) for w in held]
        fields = ("xy", "source", "first_step", "window_id", "ped_id", "row")
        joined = {f: np.concatenate([getattr(w, f) for w in held]) for f in fields}
        # window ids count from 0 in each part: the val part's move past the train part's, so windows stay apart
        joined["window_id"][len(held[0]) :] += held[0].window_id.max(initial=-1) + 1
        return AgentWindows(**joined)

    import fftool.stages.goal as goal_stage

    goal_stage.load_agent_windows = without if select_in_scene else load
    globals()["load_agent_windows"] = load


def _corner_world_to_cells(points, center, R, res, size):  # type: ignore[no-untyped-def]
    local = torch.einsum("bji,bpj->bpi", R, points - center[:, None, :])
    return local / res + size / 2 - 0.5


def _corner_cells_to_world(cells, center, R, res, size):  # type: ignore[no-untyped-def]
    local = (cells - size / 2 + 0.5) * res
    return torch.einsum("bij,bpj->bpi", R, local) + center[:, None, :]


def measure(
    lever: str,
    benchmark: str,
    profile: Path,
    extra: list[str],
    root: Path,
    rescore: list[str],
    runtime: Runtime,
    holdout: bool = False,
    step_scale: float = 1.0,
    blank_maps: bool = False,
    select_in_scene: bool = False,
    curves: Path | None = None,
    ensemble: tuple[str, ...] = (),
    place: str | None = None,
) -> list[dict[str, object]]:
    """The lever's rows for one benchmark; with `holdout`, validated on `place` (default HOLDOUT[benchmark])."""
    overrides, patches = LEVERS[lever]
    for name in patches:
        _patch(name)
    held = held_out_place(benchmark, place) if holdout else None
    if held:  # its own store: the goal artifact's fingerprint does not know which windows it read
        _hold_out(held, select_in_scene)
    store = ArtifactStore(root / _store_name(lever, held, select_in_scene))
    other_place = _named_place(benchmark, held)
    started = time.perf_counter()
    device = devices.resolve(runtime.device)
    if lever == "constant_velocity":
        cfg = load_config(profile, extra)
        windows = pipeline.run(cfg, store, ["windows"], runtime=runtime)["windows"]
        return _constant_velocity_rows(windows, benchmark, cfg.goals, held, step_scale)
    if rescore or step_scale != 1 or blank_maps or ensemble:  # the lever's models as trained, scored another way
        goal = _trained(store, benchmark)
        windows, maps = (store.lookup(kind, goal.manifest.sources[kind]) for kind in ("windows", "maps"))
    else:
        cfg = load_config(profile, [*overrides, *extra])
        built = pipeline.run(cfg, store, ["goal"], runtime=runtime, benchmark=benchmark)
        goal, windows, maps = built["goal"], built["windows"], built["maps"]
    seconds = time.perf_counter() - started
    if curves:
        validation = _validation(held, 1, select_in_scene)
        _append(curves, _curve_rows(goal, _label(lever, [], 1, select_in_scene, other_place), benchmark, validation))
    model, goal_cfg, sampling = goal_model.load_model(goal, device)
    if ensemble:
        stores = [ArtifactStore(root / _store_name(other, held, select_in_scene)) for other in ensemble]
        model = ProbabilityMean(
            [model, *(goal_model.load_model(_trained(other, benchmark), device)[0] for other in stores)]
        )
    cv_goals = 0
    if rescore:  # goals.cv_goals=m is no profile key: the last m of the K goals become constant-velocity goals
        values = _values(rescore, "goals")
        cv_goals = int(values.pop("cv_goals", 0))  # type: ignore[call-overload]
        sampling = GoalsConfig.model_validate(sampling.model_dump() | values)
    scene_maps = load_goal_scenes(maps, windows, benchmark, goal_cfg).to(device)
    if blank_maps:  # what `fftool predict` and the API give the module on a user's data: no scene map
        scene_maps = dataclasses.replace(scene_maps, stack=torch.zeros_like(scene_maps.stack))
    val = load_agent_windows(windows, benchmark, "val")
    if step_scale != 1:
        val = _resampled(windows, val, step_scale)
    obs_len, pred_len = int(windows.manifest.stats["obs_len"]), int(windows.manifest.stats["pred_len"])
    fde = _val_fde(model, val, scene_maps, goal_cfg, sampling, obs_len, pred_len, device, cv_goals)
    label = _label(
        "+".join([lever, *ensemble]),
        [*rescore, *(["maps=blank"] * blank_maps)],
        step_scale,
        select_in_scene,
        other_place,
    )
    rows = []
    for radius, (fde_k, fde_1) in fde.items():
        rows.append(
            {
                "lever": label,
                "benchmark": benchmark,
                "validation": _validation(held, step_scale, select_in_scene),
                "mode_radius_cells": radius,
                "val_goal_fde@20_m": round(fde_k, 4),
                "val_goal_fde@1_m": round(fde_1, 4),
                "val_agent_windows": len(val),
                "best_epoch": goal.manifest.stats.get("best_epoch"),
                "build_s": round(float(goal.manifest.stats.get("build_seconds", seconds)), 1),
                "threads": torch.get_num_threads(),
                "device": device.type,
                "goal_fingerprint": goal.fingerprint,
                "overrides": " ".join([*overrides, *extra]),
                "patches": " ".join(patches),
            }
        )
    return rows


def held_out_place(benchmark: str, place: str | None) -> str:
    """The place benchmark B's --holdout validation holds out: `place`, or HOLDOUT[B]. Any place B trains on will
    do: its windows come from B's train and val parts, never the test part (zara for zara1 is crowds_zara02 and 03)."""
    place = place or HOLDOUT[benchmark]
    if set(PLACES[place]) <= set(scenes.BENCHMARK_TEST_SOURCES[benchmark]):  # type: ignore[index]
        raise SystemExit(f"--place {place}: {benchmark} does not train there (its test scene); nothing to hold out")
    return place


def _named_place(benchmark: str, place: str | None) -> str | None:
    """The held-out place as the CSV's lever column names it: only where it is not HOLDOUT's."""
    return place if place and place != HOLDOUT[benchmark] else None


def _store_name(lever: str, place: str | None, select_in_scene: bool) -> str:
    """A lever's own artifact root: with a held-out place, the goal artifact's fingerprint does not know which
    windows it read, so each held-out place (and selection) gets its own."""
    if place is None:
        return lever
    return f"{lever}@holdout-{place}" + ("-in-scene" if select_in_scene else "")


class ProbabilityMean(torch.nn.Module):
    """Goal U-Nets as one: the logits of the mean of their per-cell probabilities, log p − log(1 − p), each a
    logsumexp of the members' log-sigmoids (the − log n of both cancels), so no probability is clipped."""

    def __init__(self, members: list[torch.nn.Module]) -> None:
        super().__init__()
        self.members = torch.nn.ModuleList(members)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        logits = torch.stack([member(x) for member in self.members])
        log_p = torch.logsumexp(torch.nn.functional.logsigmoid(logits), 0)
        log_not_p = torch.logsumexp(torch.nn.functional.logsigmoid(-logits), 0)
        return log_p - log_not_p


def _label(
    lever: str, rescore: list[str], step_scale: float, select_in_scene: bool = False, place: str | None = None
) -> str:
    """The CSV's lever column: the lever, then how its models were rescored (and chosen), then the held-out place
    where it is not HOLDOUT's (`place`), so that the tables, which key rows by lever and benchmark, keep it apart."""
    scaled = [f"step_scale={step_scale:.4g}"] if step_scale != 1 else []
    chosen = ["best_epoch=val_part"] if select_in_scene else []
    return " ".join([lever, *rescore, *scaled, *chosen, *([f"place={place}"] if place else [])])


def _validation(place: str | None, step_scale: float, select_in_scene: bool = False) -> str:
    """The CSV's validation column: which windows were scored (and, if not those, which chose the best epoch)."""
    where = f"held-out {place}" if place else "val part"
    where += " (best epoch by the val part)" if select_in_scene else ""
    return where + (f", steps of {step_scale:.4g} steps" if step_scale != 1 else "")


def _curve_rows(goal: Artifact, lever: str, benchmark: str, validation: str) -> list[dict[str, object]]:
    """The goal U-Net's training log, one row per epoch: the validation the trainer chose its best epoch on."""
    with (goal.path / "log.csv").open(newline="") as handle:
        log = list(csv.DictReader(handle))
    return [
        {
            "lever": lever,
            "benchmark": benchmark,
            "validation": validation,
            "epoch": int(row["epoch"]),
            "seconds": round(float(row["seconds"]), 2),
            "val_subset_goal_fde@20_m": round(float(row["val_goal_fde@20_m"]), 4),
            "val_subset_goal_fde@1_m": round(float(row["val_goal_fde@1_m"]), 4),
        }
        for row in log
    ]


def _cv_goals(
    xy: torch.Tensor, obs_len: int, pred_len: int, k: int, sampling: GoalsConfig, gen: torch.Generator
) -> torch.Tensor:
    """(M, k, 2) constant-velocity end points of windows xy (M, L, 2), drawn as sample-goals' CV@K draws them."""
    futures = protocols.constant_velocity(
        xy[:, None, :obs_len], pred_len, k, sampling.cv_angle_std_deg, sampling.cv_speed_std, gen
    )
    return futures[:, :, 0, -1]


def _constant_velocity_rows(
    windows: Artifact, benchmark: str, sampling: GoalsConfig, place: str | None, step_scale: float
) -> list[dict[str, object]]:
    """CV@K and CV@1 on the validation windows, one row per mode radius (a network-free reference)."""
    val = load_agent_windows(windows, benchmark, "val")
    val = _resampled(windows, val, step_scale) if step_scale != 1 else val
    obs_len = int(windows.manifest.stats["obs_len"])
    xy = torch.as_tensor(val.xy, dtype=torch.float32)
    gen = generator(sampling.seed, torch.device("cpu"))
    goals = _cv_goals(xy, obs_len, xy.shape[1] - obs_len, sampling.k, sampling, gen)
    errors = torch.linalg.vector_norm(goals - xy[:, None, -1], dim=-1)
    return [
        {
            "lever": _label("constant_velocity", [], step_scale, place=_named_place(benchmark, place)),
            "benchmark": benchmark,
            "validation": _validation(place, step_scale),
            "mode_radius_cells": radius,
            "val_goal_fde@20_m": round(float(errors.min(1).values.mean()), 4),
            "val_goal_fde@1_m": round(float(errors[:, 0].mean()), 4),
            "val_agent_windows": len(val),
        }
        for radius in MODE_RADII
    ]


def _resampled(windows: Artifact, like: AgentWindows, scale: float) -> AgentWindows:
    """Windows of the tracks behind `like` (its sources, the train and val splits), resampled at one step every
    `scale` recorded steps by linear interpolation, from every start where a pedestrian is seen throughout: with
    scale 5/3 another scene's 0.4 s steps become eth's 0.67 s (12 steps are 8 s), and, as on eth, only the
    pedestrians who stay in view that long keep a window."""
    tracks_artifact = ArtifactStore(windows.path.parent.parent).lookup("tracks", windows.manifest.sources["tracks"])
    sources = sorted(set(like.source))
    filters = [("source", "in", sources), ("split", "in", ["train", "val"])]
    tracks = pq.read_table(tracks_artifact.file(TRACKS_FILE), filters=filters).to_pandas()
    track = tracks.groupby(["source", "split", "ped_id"], observed=True).ngroup().to_numpy()
    order = np.lexsort((tracks["step"].to_numpy(), track))
    track, step = track[order], tracks["step"].to_numpy()[order]
    points = tracks[["x", "y"]].to_numpy()[order]
    # rows in runs of consecutive steps of one track (as dataset.windowing.slice_sequence), each row's run's last row
    new_run = np.r_[True, (track[1:] != track[:-1]) | (step[1:] != step[:-1] + 1)]
    run_last = np.r_[np.flatnonzero(new_run)[1:] - 1, len(step) - 1][np.cumsum(new_run) - 1]
    offsets = np.arange(int(windows.manifest.stats["window_len"])) * scale
    starts = np.flatnonzero(run_last - np.arange(len(step)) >= offsets[-1] - 1e-9)  # no step past the run
    times = starts[:, None] + offsets  # (S, length) in sorted rows
    below = np.floor(times).astype(np.int64)
    above = np.minimum(below + 1, run_last[starts][:, None])
    fraction = (times - below)[..., None]
    xy = points[below] + (points[above] - points[below]) * fraction
    minus = np.full(len(starts), -1)
    source = tracks["source"].astype(str).to_numpy()[order][starts]
    return AgentWindows(xy, source, minus, minus, tracks["ped_id"].to_numpy()[order][starts], minus)


def _trained(store: ArtifactStore, benchmark: str) -> Artifact:
    """The newest goal U-Net of `benchmark` in a lever's store."""
    found = [a for a in store.list("goal") if a.manifest.params.get("benchmark") == benchmark]
    if not found:
        raise SystemExit(f"{store.root}: no goal U-Net of {benchmark} to rescore; run the lever first")
    return max(found, key=lambda a: a.manifest.created_at)


def _values(assignments: list[str], section: str) -> dict[str, object]:
    """`section.key=value` (TOML values) -> {key: value}."""
    parsed = {}
    for text in assignments:
        dotted, _, value = text.partition("=")
        name, _, key = dotted.partition(".")
        if name != section:
            raise SystemExit(f"--rescore {text}: expected {section}.<key>=<value>")
        parsed[key] = tomllib.loads(f"v = {value}")["v"]
    return parsed


@torch.no_grad()
def _val_fde(  # type: ignore[no-untyped-def]
    model, val, scene_maps, goal_cfg, sampling, obs_len, pred_len, device, cv_goals=0
) -> dict[int, tuple[float, float]]:
    """Goal-FDE@K and @1 per mode radius, as `goal_model.evaluate` computes them, with the TTST draws made once:
    the mode takes no random draw, so only goal 1 differs between radii. With cv_goals = m, goals K-m+1..K are
    replaced by m constant-velocity goals (the first exact, the others turned and scaled as CV@K's)."""
    gen, cv_gen = generator(goal_cfg.seed, device), generator(sampling.seed, device)
    scene = goal_scene_index(scene_maps, val, goal_cfg, cross_fit=False).to(device)
    errors: dict[int, list[torch.Tensor]] = {radius: [] for radius in MODE_RADII}
    neighbours = goal_model.Neighbours.of(val.xy, val.window_id) if goal_cfg.neighbour_channels else None
    for start in range(0, len(val), 1024):
        index = slice(start, start + 1024)
        xy = torch.as_tensor(val.xy[index], dtype=torch.float32, device=device)
        zeros = torch.zeros(len(xy), device=device)
        others = None if neighbours is None else neighbours.observed(index, obs_len).to(device)
        x, center, R = goal_model.goal_inputs(
            xy[:, :obs_len], scene[index], scene_maps, goal_cfg, zeros, zeros.bool(), pred_len, others
        )
        logits = model(x)[:, -1]
        cells = heatmaps.sample_goals(
            logits, sampling.k, method=sampling.method, temperature=sampling.temperature,
            threshold=sampling.threshold, samples=sampling.samples, iterations=sampling.kmeans_iterations,
            generator=gen,
        )  # fmt: skip
        if cv_goals:
            cv = _cv_goals(xy, obs_len, pred_len, cv_goals, sampling, cv_gen)
        for radius in MODE_RADII:
            cells[:, 0] = heatmaps.refine_mode(logits, radius, sampling.temperature)
            goals = heatmaps.cells_to_world(cells, center, R, goal_cfg.resolution_m, goal_cfg.crop_cells)
            if cv_goals:
                goals[:, -cv_goals:] = cv
            errors[radius].append(torch.linalg.vector_norm(goals - xy[:, None, -1], dim=-1))
    return {
        radius: (float(torch.cat(e).min(1).values.mean()), float(torch.cat(e)[:, 0].mean()))
        for radius, e in errors.items()
    }


def _append(out: Path, rows: list[dict[str, object]]) -> None:
    """Append `rows` to the CSV; a file written before a column was added is rewritten with it (empty)."""
    fields = list(rows[0])
    kept: list[dict[str, str]] = []
    if out.exists():
        with out.open(newline="") as handle:
            reader = csv.DictReader(handle)
            if reader.fieldnames != fields:
                kept = list(reader)
                fields = [*(reader.fieldnames or []), *(f for f in fields if f not in (reader.fieldnames or []))]
    if kept or not out.exists():
        with out.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=fields, restval="")
            writer.writeheader()
            writer.writerows(kept)
    with out.open("a", newline="") as handle:
        csv.DictWriter(handle, fieldnames=fields, restval="").writerows(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--lever", required=True, choices=list(LEVERS), help="one lever per process (patches stay)")
    parser.add_argument("--benchmarks", default="all")
    parser.add_argument("--profile", type=Path, default=Path("pipelines/cpu.toml"))
    parser.add_argument("--set", dest="extra", action="append", default=[], help="more overrides, e.g. goal.epochs=16")
    parser.add_argument(
        "--rescore", action="append", default=[], help="score the lever's trained models with goals.<key>=<value>"
    )
    parser.add_argument("--root", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / "fftool_goal_levers")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/goal_levers.csv"))
    parser.add_argument("--device", default="cpu", help="cpu or cuda (the levers beyond the CPU budget)")
    parser.add_argument("--holdout", action="store_true", help="validate on a place held out of training (HOLDOUT)")
    parser.add_argument(
        "--place", choices=list(PLACES), help="with --holdout: hold out this training place instead of HOLDOUT's"
    )
    parser.add_argument(
        "--step-scale",
        type=float,
        default=1.0,
        help="score trained models on windows resampled at this step (5/3: eth's)",
    )
    parser.add_argument(
        "--blank-maps", action="store_true", help="score trained models with every map channel 0 (as on a user's data)"
    )
    parser.add_argument(
        "--select-in-scene",
        action="store_true",
        help="with --holdout: choose the best epoch on the val part (as shipped), score on the held-out place",
    )
    parser.add_argument("--curves", type=Path, help="append the trained model's per-epoch validation to this CSV")
    parser.add_argument(
        "--ensemble", action="append", default=[], choices=list(LEVERS), help="score with this lever's models too"
    )
    args = parser.parse_args()
    if (args.step_scale != 1 or args.select_in_scene or args.place) and not args.holdout:
        parser.error("--step-scale, --select-in-scene and --place read a held-out place: they need --holdout")
    assert VERSIONS["goal"] >= 2, "this measurement needs the cell-centred crop code"
    benchmarks = list(BENCHMARKS) if args.benchmarks == "all" else args.benchmarks.split(",")
    for benchmark in benchmarks:
        rows = measure(
            args.lever,
            benchmark,
            args.profile,
            args.extra,
            args.root,
            args.rescore,
            Runtime(args.device),
            args.holdout,
            args.step_scale,
            args.blank_maps,
            args.select_in_scene,
            args.curves,
            tuple(args.ensemble),
            args.place,
        )
        _append(args.out, rows)
        for row in rows:
            print(
                f"{args.lever:>16} {benchmark:>6} r={row['mode_radius_cells']}  @20 {row['val_goal_fde@20_m']:.3f}"
                f"  @1 {row['val_goal_fde@1_m']:.3f}  {row.get('build_s', '')} s",
                flush=True,
            )


if __name__ == "__main__":
    main()
