"""Evaluate a predictor on one benchmark's test part: K samples per valid agent-window, minADE/minFDE, NC.

Reads: windows and, for the CVAE predictor, the trained `cvae` artifact, the forces arrays its variant
samples with (dr: desired speeds; re: and groups) and, for goal variants under the paper or fair
protocol, the sampled `goals`.
Writes: `evaluate/<fp>/predictions.parquet` (every sample of every agent-window, with its per-agent
metrics, so tables can be recomputed without sampling again) and the summary in the manifest.
Run: `fftool evaluate --benchmarks zara1 --variant dr --protocol paper`.

Sampling batches many windows per forward pass (padded agents, masked attention), draws the K samples
of a window in one pass with the context shared between samples, and recomputes the social forces
from the predicted positions at every decoding step.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import torch

from fftool.artifacts.schema import COMMANDS, PREDICTIONS_FILE, VERSIONS
from fftool.artifacts.store import Artifact
from fftool.config import EvaluateConfig, PipelineConfig, variant_section
from fftool.errors import FftoolError
from fftool.learning.batches import SceneBatch, load_scene_set
from fftool.learning.cvae_model import load_model
from fftool.learning.dlow_model import load_sampler
from fftool.learning.sampling import Predictor, collect, load_sampled_goals, plan_batches, sample_batches
from fftool.science.metrics import agent_metrics, collision_count
from fftool.stages.contract import Reads, Stage, StageContext
from fftool.variants import SPECS, reads_goal

NAME: Final = "evaluate"

METRIC_DEFINITIONS: Final = {
    "min_ade": "mean over agent-windows of min over K samples of the mean over the T future steps of the "
    "unsquared Euclidean error (m)",
    "min_fde": "mean over agent-windows of min over K samples of the error at step T (m), independent of the ADE min",
    "nc": "sum over windows of the (m, n, t) with m != n real agents of the window and ||y_m^t - y_n^t|| < gamma, "
    "each agent on its best-ADE sample (paper); ordered pairs (each contact twice); unordered = ordered / 2; "
    "joint = one sample per window, the one with the smallest summed ADE",
    "col": "COL (EigenTrajectory, SingularTrajectory utils/metrics.py compute_batch_col): mean over agent-windows "
    "of the % of the K samples whose path comes strictly within 0.2 m of another real agent's sample with the "
    "same index (the K samples are drawn jointly per window), on the first 14 points of the paths interpolated "
    "at 4 points per step (the first 3.25 steps after the first predicted position); independent of gamma",
    "col_gt": "Col-II (Trajnet++ trajnetplusplustools metrics.collision, person_radius 0.1 m): number of "
    "agent-windows whose best-ADE sample comes within 0.2 m (<=) of another real agent's ground truth at the "
    "same time, on both paths split at 2 points per step; rate = col_gt / agent_windows; independent of gamma",
}
METRIC_COLUMNS: Final = ("min_ade", "min_fde", "best_k", "collisions", "joint_collisions", "col", "col_gt")


def predictor_of(cfg: PipelineConfig) -> str:
    """The predictor an evaluation scores: cv, or the CVAE variant of the cvae section."""
    return "cv" if cfg.evaluate.predictor == "cv" else cfg.cvae.variant


def codes_of(cfg: PipelineConfig) -> Literal["mean", "dlow", "prior"]:
    """Where an evaluation's CVAE takes the codes of its K futures: the prior's mean for each goal (a goal variant
    under the fair protocol with `fair_code = "mean"`), its DLow sampler (a variant of `dlow.variants`), or draws
    from its prior (cv: its own noise, reported as prior draws)."""
    predictor, evaluate = predictor_of(cfg), variant_section(cfg, "evaluate")
    assert isinstance(evaluate, EvaluateConfig)
    if evaluate.mean_codes(predictor):
        return "mean"
    return "dlow" if predictor in cfg.dlow.variants else "prior"


def declare(cfg: PipelineConfig) -> Reads:
    """Only what the predictor and protocol read: the goal protocol only for predictors that read a goal (so
    the baseline and cv evaluations are shared by every protocol), the fair protocol's code only under it, the
    sampled goals unless the protocol is the oracle, the DLow sampler unless each goal decodes the prior's mean,
    the constant-velocity noise only for cv, the forces arrays sampling uses (dr, re)."""
    predictor, evaluate = predictor_of(cfg), variant_section(cfg, "evaluate")
    assert isinstance(evaluate, EvaluateConfig)
    shared = tuple(f"evaluate.{key}" for key in EvaluateConfig.model_fields if key not in _PER_PREDICTOR)
    if predictor == "cv":
        return Reads(
            params=(*shared, "evaluate.cv_angle_std_deg", "evaluate.cv_speed_std"),
            artifacts={"windows": None},
            command=" --variant cv",
        )
    goal = reads_goal(predictor)
    fair = goal and evaluate.protocol == "fair"
    arrays = SPECS[predictor].sampling_reads
    artifacts: dict[str, tuple[str, ...] | None] = {"windows": None, **({"forces": arrays} if arrays else {})}
    artifacts["cvae"] = None
    if codes_of(cfg) == "dlow":  # AgentFormer's test-time sampler over that CVAE
        artifacts["dlow"] = None
    if goal and evaluate.protocol != "oracle":
        artifacts["goals"] = None
    return Reads(
        params=(*shared, *(("evaluate.protocol",) if goal else ()), *(("evaluate.fair_code",) if fair else ())),
        artifacts=artifacts,
        command=f" --variant {predictor}" + (f" --protocol {evaluate.protocol}" if goal else ""),
    )


# The evaluate keys only some predictors read (`declare`): the goal protocol and the fair protocol's code, the
# constant-velocity noise.
_PER_PREDICTOR: Final = frozenset({"protocol", "fair_code", "cv_angle_std_deg", "cv_speed_std"})


def _predictions_table(columns: dict[str, np.ndarray], k: int, pred_len: int) -> pa.Table:
    flat = lambda a, n: pa.FixedSizeListArray.from_arrays(pa.array(a.reshape(-1), pa.float32()), n)  # noqa: E731
    return pa.table(
        {
            "window_id": pa.array(columns["window_id"], pa.int64()),
            "ped_id": pa.array(columns["ped_id"], pa.int64()),
            "agent_row": pa.array(columns["row"], pa.int64()),  # row of the windows artifact's agent_windows
            "n_agents": pa.array(columns["n_agents"], pa.int32()),  # valid agents in the window
            "min_ade": pa.array(columns["min_ade"], pa.float32()),
            "min_fde": pa.array(columns["min_fde"], pa.float32()),
            "best_k": pa.array(columns["best_k"], pa.int16()),
            "collisions": pa.array(columns["collisions"], pa.int32()),
            "joint_collisions": pa.array(columns["joint_collisions"], pa.int32()),
            "goal": flat(columns["goal"], 2 * k),  # (K, 2) the goal of each sample, world metres
            "pred": flat(columns["pred"], 2 * k * pred_len),  # (K, T, 2) sample-major, world metres
        }
    )


def sample_and_score(
    cfg: EvaluateConfig,
    benchmark: str,
    windows: Artifact,
    forces: Artifact | None,
    cvae: Artifact | None,
    goals: Artifact | None,
    out_dir: Path,
    device: torch.device,
    on_progress: Callable[[str, int, int], None] | None = None,
    dlow: Artifact | None = None,
) -> dict[str, Any]:
    """Sample, score and save every valid agent-window of the benchmark's evaluation part (through the DLow
    sampler `dlow` of the CVAE when given one, else from the CVAE's prior)."""
    obs_len = int(windows.manifest.stats["obs_len"])
    pred_len = int(windows.manifest.stats["pred_len"])
    reads = SPECS[cvae.manifest.params["variant"]].sampling_reads if cvae is not None else ()
    scenes = load_scene_set(windows, forces, benchmark, cfg.part, reads=reads)
    # Count agent-windows, not windows: an empty part still has one (empty) window in scenes.window_start.
    if len(scenes.data) == 0:
        raise FftoolError(_no_agent_windows(benchmark, cfg.part, obs_len + pred_len))
    sampled = load_sampled_goals(goals, scenes, benchmark, cfg.part) if goals is not None else None
    trained = load_model(cvae, device) if cvae is not None else None
    sampler = load_sampler(dlow, device) if dlow is not None else None
    if sampler is not None and sampler.k != cfg.k:
        raise FftoolError(
            f"the DLow sampler {dlow.id} draws {sampler.k} futures per agent, evaluate.k is {cfg.k}: "
            f"set dlow.k = evaluate.k and rebuild it with `fftool train-dlow`"
        )
    predictor = Predictor(cfg, trained, sampled, obs_len, pred_len, device, sampler)
    plan = plan_batches(scenes, cfg)

    def scored(batch: SceneBatch, goals_k: torch.Tensor, futures: torch.Tensor) -> dict[str, Any]:
        metrics = agent_metrics(futures, batch.xy[:, :, obs_len:], batch.agent_mask, cfg.collision_threshold_m)
        n_agents = batch.agent_mask.sum(1, keepdim=True).expand_as(batch.agent_mask)
        return {"n_agents": n_agents, **{name: getattr(metrics, name) for name in METRIC_COLUMNS}} | {
            "goal": goals_k.transpose(1, 2),
            "pred": futures.transpose(1, 2),
        }

    def reported(batches: Iterable[tuple[SceneBatch, torch.Tensor, torch.Tensor]]) -> Iterator[Any]:
        for done, item in enumerate(batches):
            yield item
            if on_progress:
                on_progress(f"evaluate {predictor.variant} ({benchmark})", done + 1, len(plan))

    started = time.perf_counter()
    with torch.no_grad():
        columns = collect(reported(sample_batches(predictor, scenes, plan, predictor.goals, device)), scored)
    seconds = time.perf_counter() - started
    position = np.searchsorted(scenes.data.row, columns["row"])
    columns["window_id"], columns["ped_id"] = scenes.data.window_id[position], scenes.data.ped_id[position]
    pq.write_table(_predictions_table(columns, cfg.k, pred_len), out_dir / PREDICTIONS_FILE)
    return summary(columns, cfg, benchmark, predictor.variant, predictor.protocol) | {
        "sampler": "dlow" if sampler is not None else ("cvae prior" if trained is not None else "constant velocity"),
        "windows": scenes.windows,
        "device": str(device),
        "torch_threads": torch.get_num_threads(),  # results depend on it (float summation order)
        "seconds": round(seconds, 2),
        "agent_windows_per_s": round(len(columns["row"]) / seconds, 1),
    }


def _no_agent_windows(benchmark: str, part: str, window_len: int | None = None) -> str:
    """Why an empty part is refused: its means would be NaN, not numbers."""
    steps = f"{window_len} consecutive steps" if window_len else "a whole window"
    return (
        f"{benchmark}/{part} has 0 valid agent-windows to evaluate: expected at least one pedestrian present "
        f"for {steps} in that part (see the windows artifact's summary)"
    )


def summary(columns: dict[str, np.ndarray], cfg: EvaluateConfig, benchmark: str, variant: str, protocol: str) -> dict:
    """The manifest's metrics: means over agent-windows and every NC variant, with their definitions."""
    if len(columns["min_ade"]) == 0:  # a mean over nothing is NaN; never report it as a metric
        raise FftoolError(_no_agent_windows(benchmark, cfg.part))
    collisions, joint = columns["collisions"], columns["joint_collisions"]
    return {
        "benchmark": benchmark,
        "part": cfg.part,
        "variant": variant,
        "protocol": protocol,
        "k": cfg.k,
        "seed": cfg.seed,
        "collision_threshold_m": cfg.collision_threshold_m,
        "agent_windows": len(columns["min_ade"]),
        "min_ade": float(np.mean(columns["min_ade"])),
        "min_fde": float(np.mean(columns["min_fde"])),
        "nc": {
            "best_ade": {pairs: collision_count(collisions, pairs) for pairs in ("ordered", "unordered")},
            "joint": {pairs: collision_count(joint, pairs) for pairs in ("ordered", "unordered")},
        },
        "col": float(np.mean(columns["col"])),
        "col_gt": int(np.sum(columns["col_gt"])),
        "definitions": METRIC_DEFINITIONS,
    }


def build(cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: StageContext) -> dict[str, Any]:
    """The stage contract: K futures per test agent-window of one benchmark, and their metrics."""
    upstream = (inputs["windows"], inputs.get("forces"), inputs.get("cvae"), inputs.get("goals"))
    args = (cfg.evaluate, ctx.need_benchmark(), *upstream, ctx.dir, ctx.device())  # the variant's own section
    return sample_and_score(*args, on_progress=ctx.on_progress, dlow=inputs.get("dlow"))


STAGE = Stage(
    NAME,
    VERSIONS[NAME],
    COMMANDS[NAME],
    label="evaluate",
    declare=declare,
    build=build,
    section="evaluate",
    per_benchmark=True,
)
