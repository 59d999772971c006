"""Evaluate a predictor on one benchmark's test part: K samples per valid agent-window, minADE/minFDE, NC.

Reads: windows and, for the CVAE predictor, the trained `cvae` artifact, the forces arrays its variant
samples with (dr: desired speeds; re: and groups) and, for goal variants under the paper or fair
protocol, the sampled `goals`.
Writes: `evaluate/<fp>/predictions.parquet` (every sample of every agent-window, with its per-agent
metrics, so tables can be recomputed without sampling again) and the summary in the manifest.
Run: `fftool evaluate --benchmark zara1 --variant dr --protocol paper`.

Sampling batches many windows per forward pass (padded agents, masked attention), draws the K samples
of a window in one pass with the context shared between samples, and recomputes the social forces
from the predicted positions at every decoding step.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from functools import partial
from pathlib import Path
from typing import Any, Final

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import torch

from fftool.artifacts.schema import GOALS_FILE, GOALS_INDEX_FILE, PREDICTIONS_FILE
from fftool.artifacts.store import Artifact, ArtifactStore, check_schema
from fftool.config import EvaluateConfig, PipelineConfig
from fftool.errors import ArtifactMissing, FftoolError
from fftool.learning.batches import AgentWindows, SceneSet, load_agent_windows, load_scene_set
from fftool.learning.cvae_model import load_model
from fftool.learning.features import SAMPLING_READS
from fftool.learning.sampling import Predictor, plan_batches, sample_batches
from fftool.science.metrics import agent_metrics, collision_count
from fftool.stages.contract import Stage, StageContext

NAME: Final = "evaluate"
VERSION: Final = 1
INPUTS: Final = ("windows", "forces", "cvae", "goals")  # at most; `reads` says which, per predictor

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
# Windows × K × agents² per rescoring pass: bounds the memory of COL's (B, K, 14, A, A) distances.
_RESCORE_PAIRS: Final = 200_000


def reads_goal(cfg: PipelineConfig) -> bool:
    """Whether the evaluated predictor takes a goal (a goal, dr or re CVAE); cv and the baseline do not."""
    return cfg.evaluate.predictor == "cvae" and cfg.cvae.variant != "baseline"


def forces_read(cfg: PipelineConfig) -> tuple[str, ...]:
    """The forces arrays an evaluation reads: none for cv, the baseline and goal (`features.SAMPLING_READS`)."""
    return SAMPLING_READS[cfg.cvae.variant] if cfg.evaluate.predictor == "cvae" else ()


def reads(cfg: PipelineConfig) -> tuple[str, ...]:
    """Upstream stages of an evaluation: only what its predictor and protocol actually read."""
    if cfg.evaluate.predictor == "cv":
        return ("windows",)
    forces = ("forces",) if forces_read(cfg) else ()
    goals = ("goals",) if reads_goal(cfg) and cfg.evaluate.protocol != "oracle" else ()
    return ("windows", *forces, "cvae", *goals)


def section(cfg: PipelineConfig) -> EvaluateConfig:
    """The evaluate parameters that matter, the others fingerprinted at their defaults: the goal protocol
    only for predictors that read a goal (so the baseline and cv evaluations are shared by every protocol),
    the constant-velocity noise only for the cv predictor."""
    default = EvaluateConfig()
    unread = {} if reads_goal(cfg) else {"protocol": default.protocol}
    if cfg.evaluate.predictor != "cv":
        unread |= {"cv_angle_std_deg": default.cv_angle_std_deg, "cv_speed_std": default.cv_speed_std}
    return cfg.evaluate.model_copy(update=unread)


def load_sampled_goals(goals: Artifact, scenes: SceneSet, benchmark: str, part: str) -> np.ndarray:
    """(M, K, 2) sampled goals aligned with the scene set's agent-windows (checked key by key)."""
    index = pq.read_table(goals.file(GOALS_INDEX_FILE)).to_pandas()
    rows = np.flatnonzero((index["benchmark"] == benchmark).to_numpy() & (index["part"] == part).to_numpy())
    if len(rows) != len(scenes.data) or not (
        np.array_equal(index["window_id"].to_numpy()[rows], scenes.data.window_id)
        and np.array_equal(index["ped_id"].to_numpy()[rows], scenes.data.ped_id)
    ):
        raise FftoolError(
            f"{goals.file(GOALS_INDEX_FILE)}: the goals of {benchmark}/{part} do not match the windows artifact "
            f"({len(rows)} goal rows for {len(scenes.data)} agent-windows); rebuild with fftool sample-goals"
        )
    return np.load(goals.file(GOALS_FILE), mmap_mode="r")[rows]


def _real_agents(values: torch.Tensor, mask: np.ndarray) -> np.ndarray:
    """(B, A, ...) -> (real agents, ...) in window-major order."""
    return values.cpu().numpy()[mask]


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
) -> dict[str, Any]:
    """Sample, score and save every valid agent-window of the benchmark's evaluation part."""
    obs_len = int(windows.manifest.stats["obs_len"])
    pred_len = int(windows.manifest.stats["pred_len"])
    reads = SAMPLING_READS[cvae.manifest.params["variant"]] if cvae is not None else ()
    scenes = load_scene_set(windows, forces, benchmark, cfg.part, reads=reads)
    # Count agent-windows, not windows: an empty part still has one (empty) window in scenes.window_start.
    if len(scenes.data) == 0:
        raise FftoolError(_no_agent_windows(benchmark, cfg.part, obs_len + pred_len))
    sampled = load_sampled_goals(goals, scenes, benchmark, cfg.part) if goals is not None else None
    trained = load_model(cvae, device) if cvae is not None else None
    predictor = Predictor(cfg, trained, sampled, obs_len, pred_len, device)
    plan = plan_batches(scenes, cfg)
    batches = sample_batches(predictor, scenes, plan, predictor.goals, device)
    parts: dict[str, list[np.ndarray]] = {}
    started = time.perf_counter()
    with torch.no_grad():
        for done, (batch, goals_k, futures) in enumerate(batches):
            metrics = agent_metrics(futures, batch.xy[:, :, obs_len:], batch.agent_mask, cfg.collision_threshold_m)
            mask = batch.agent_mask.cpu().numpy()
            take = partial(_real_agents, mask=mask)
            found = {
                "row": take(batch.row),
                "n_agents": np.broadcast_to(mask.sum(1, keepdims=True), mask.shape)[mask],
                "min_ade": take(metrics.min_ade),
                "min_fde": take(metrics.min_fde),
                "best_k": take(metrics.best_k),
                "collisions": take(metrics.collisions),
                "joint_collisions": take(metrics.joint_collisions),
                "col": take(metrics.col),
                "col_gt": take(metrics.col_gt),
                "goal": take(goals_k.transpose(1, 2)),
                "pred": take(futures.transpose(1, 2)),
            }
            for name, values in found.items():
                parts.setdefault(name, []).append(values)
            if on_progress:
                on_progress(f"evaluate {predictor.variant} ({benchmark})", done + 1, len(plan))
    seconds = time.perf_counter() - started
    columns = {name: np.concatenate(values) for name, values in parts.items()}
    order = np.argsort(columns["row"])
    columns = {name: values[order] for name, values in columns.items()}
    position = np.searchsorted(scenes.data.row, columns["row"])
    columns["window_id"], columns["ped_id"] = scenes.data.window_id[position], scenes.data.ped_id[position]
    pq.write_table(_predictions_table(columns, cfg.k, pred_len), out_dir / PREDICTIONS_FILE)
    return summary(columns, cfg, benchmark, predictor.variant, predictor.protocol) | {
        "windows": scenes.windows,
        "device": str(device),
        "torch_threads": torch.get_num_threads(),  # results depend on it (float summation order)
        "seconds": round(seconds, 2),
        "agent_windows_per_s": round(len(order) / seconds, 1),
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


def rescore(predictions: pd.DataFrame, data: AgentWindows, k: int, threshold_m: float) -> dict[str, np.ndarray]:
    """Per-agent metrics recomputed from saved predictions (e.g. at another γ) without sampling again.

    predictions: an evaluation's predictions.parquet; data: the agent-windows of the same part (for
    the ground truth). Returns the predictions file's metric columns and COL and Col-II (METRIC_COLUMNS),
    in its row order. Windows are scored in passes of at most _RESCORE_PAIRS windows × K × agents².
    """
    position = np.searchsorted(data.row, predictions["agent_row"].to_numpy())
    pred = np.stack(predictions["pred"].to_numpy()).reshape(len(predictions), k, -1, 2)
    truth = data.xy[position, -pred.shape[2] :]
    windows = predictions["window_id"].to_numpy()
    starts = np.r_[0, np.flatnonzero(np.diff(windows)) + 1, len(windows)]
    slot = np.arange(len(windows)) - np.repeat(starts[:-1], np.diff(starts))
    B, A = len(starts) - 1, int(np.diff(starts).max())
    which = np.repeat(np.arange(B), np.diff(starts))
    padded_pred = torch.zeros(B, A, k, pred.shape[2], 2)
    padded_truth = torch.zeros(B, A, pred.shape[2], 2)
    mask = torch.zeros(B, A, dtype=torch.bool)
    padded_pred[which, slot] = torch.as_tensor(pred, dtype=torch.float32)
    padded_truth[which, slot] = torch.as_tensor(truth, dtype=torch.float32)
    mask[which, slot] = True
    step = max(1, _RESCORE_PAIRS // (k * A * A))
    passes = [
        agent_metrics(padded_pred[lo : lo + step].transpose(1, 2), padded_truth[lo : lo + step], mask[lo : lo + step],
                      threshold_m)
        for lo in range(0, B, step)
    ]  # fmt: skip
    return {name: torch.cat([getattr(m, name) for m in passes])[which, slot].numpy() for name in METRIC_COLUMNS}


def rescore_artifact(store: ArtifactStore, evaluation: Artifact, threshold_m: float) -> dict[str, Any]:
    """An evaluate artifact's summary recomputed from its saved predictions with collision threshold
    `threshold_m` (command `fftool rescore`): no sampling, so only the NC counts can change; COL and Col-II
    are computed for evaluations built before they existed."""
    columns = rescored_columns(store, evaluation, threshold_m)  # checks first that it is an evaluation
    stats = evaluation.manifest.stats
    cfg = EvaluateConfig(part=stats["part"], k=stats["k"], seed=stats["seed"], collision_threshold_m=threshold_m)
    return summary(columns, cfg, stats["benchmark"], stats["variant"], stats["protocol"])


def rescored_columns(store: ArtifactStore, evaluation: Artifact, threshold_m: float) -> dict[str, np.ndarray]:
    """An evaluation's per-agent metric columns (METRIC_COLUMNS) recomputed from its saved predictions, NC at
    `threshold_m`, with each row's window_id: what `rescore` prints and what the report's intervals resample."""
    check_schema(evaluation, NAME, VERSION, "fftool evaluate")
    windows = store.lookup("windows", evaluation.manifest.built_from()["windows"])
    if windows is None:
        raise ArtifactMissing(
            f"the windows artifact {evaluation.id} was built from is no longer under {store.root}; run `fftool ingest`"
        )
    store.check_inputs(
        {"evaluate": evaluation, "windows": windows}, {"evaluate": "fftool evaluate", "windows": "fftool ingest"}
    )
    stats = evaluation.manifest.stats
    predictions = pd.read_parquet(evaluation.file(PREDICTIONS_FILE), columns=["window_id", "agent_row", "pred"])
    data = load_agent_windows(windows, stats["benchmark"], stats["part"])
    return rescore(predictions, data, stats["k"], threshold_m) | {"window_id": predictions["window_id"].to_numpy()}


def build(cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: StageContext) -> dict[str, Any]:
    """The stage contract: K futures per test agent-window of one benchmark, and their metrics."""
    upstream = (inputs["windows"], inputs.get("forces"), inputs.get("cvae"), inputs.get("goals"))
    args = (cfg.evaluate, ctx.need_benchmark(), *upstream, ctx.out_dir, ctx.device())
    return sample_and_score(*args, on_progress=ctx.on_progress)


STAGE = Stage(
    NAME,
    VERSION,
    INPUTS,
    command="fftool evaluate",
    section=section,
    build=build,
    description=lambda cfg, benchmark: f"evaluate ({benchmark})",
    per_benchmark=True,
    needs=reads,
    reads=lambda cfg: {"forces": forces_read(cfg)},
    command_args=lambda cfg: (
        (" --variant cv" if cfg.evaluate.predictor == "cv" else f" --variant {cfg.cvae.variant}")
        + (f" --protocol {cfg.evaluate.protocol}" if reads_goal(cfg) else "")
    ),
)
