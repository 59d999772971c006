"""Re-scoring saved predictions: every metric recomputed from an evaluation's predictions.parquet, without
sampling again (`fftool rescore`, the report's intervals, COL and Col-II for evaluations made before them)."""

from __future__ import annotations

from typing import Any, Final

import numpy as np
import pandas as pd
import torch

from fftool.artifacts.schema import PREDICTIONS_FILE
from fftool.artifacts.store import Artifact, ArtifactStore, check_schema
from fftool.config import EvaluateConfig
from fftool.errors import ArtifactMissing
from fftool.learning.batches import AgentWindows, load_agent_windows
from fftool.science.metrics import agent_metrics
from fftool.stages.evaluate import METRIC_COLUMNS, summary

# Windows × K × agents² per rescoring pass: bounds the memory of COL's (B, K, 14, A, A) distances.
_RESCORE_PAIRS: Final = 200_000
# What rescoring gives: the predictions file's metric columns, and the joint metrics (JADE, JFDE) beside them.
SCORED_COLUMNS: Final = (*METRIC_COLUMNS, "joint_ade", "joint_fde")


def rescore(predictions: pd.DataFrame, data: AgentWindows, k: int, threshold_m: float) -> dict[str, np.ndarray]:
    """Per-agent metrics recomputed from saved predictions (e.g. at another γ) without sampling again.

    predictions: an evaluation's predictions.parquet; data: the agent-windows of the same part (for
    the ground truth). Returns the predictions file's metric columns with COL and Col-II (METRIC_COLUMNS) and
    the joint ADE/FDE (SCORED_COLUMNS), in its row order. Windows are scored in passes of at most
    _RESCORE_PAIRS windows × K × agents².
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
    return {name: torch.cat([getattr(m, name) for m in passes])[which, slot].numpy() for name in SCORED_COLUMNS}


def rescore_artifact(store: ArtifactStore, evaluation: Artifact, threshold_m: float) -> dict[str, Any]:
    """An evaluate artifact's summary recomputed from its saved predictions with collision threshold
    `threshold_m` (command `fftool rescore`): no sampling, so only the NC counts can change; COL and Col-II
    are computed for evaluations built before they existed."""
    columns = rescored_columns(store, evaluation, threshold_m)  # checks first that it is an evaluation
    stats = evaluation.manifest.stats
    cfg = EvaluateConfig(part=stats["part"], k=stats["k"], seed=stats["seed"], collision_threshold_m=threshold_m)
    return summary(columns, cfg, stats["benchmark"], stats["variant"], stats["protocol"])


def rescored_columns(store: ArtifactStore, evaluation: Artifact, threshold_m: float) -> dict[str, np.ndarray]:
    """An evaluation's per-agent metric columns (SCORED_COLUMNS) recomputed from its saved predictions, NC at
    `threshold_m`, with each row's window_id: what `rescore` prints and what the report's intervals resample."""
    check_schema(evaluation, "evaluate")
    windows = store.lookup("windows", evaluation.manifest.built_from()["windows"])
    if windows is None:
        raise ArtifactMissing(
            f"the windows artifact {evaluation.id} was built from is no longer under {store.root}; run `fftool ingest`"
        )
    store.check_inputs({"evaluate": evaluation, "windows": windows})
    stats = evaluation.manifest.stats
    predictions = pd.read_parquet(evaluation.file(PREDICTIONS_FILE), columns=["window_id", "agent_row", "pred"])
    data = load_agent_windows(windows, stats["benchmark"], stats["part"])
    return rescore(predictions, data, stats["k"], threshold_m) | {"window_id": predictions["window_id"].to_numpy()}
