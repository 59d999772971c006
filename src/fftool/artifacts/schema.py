"""Every artifact kind's schema version, the command that makes it, its file names and Arrow schemas: the
contract between stages, and between the store's writers and every reader (stages, `predict`, the API).

Stages never import each other; they agree on these names and file names instead.
"""

from __future__ import annotations

from typing import Final

import pyarrow as pa

# The schema version of each artifact kind: a reader refuses an artifact written under another one
# (store.check_schema). forces 2: the time step is recorded (dt_s); 3: windows centred on a valid agent.
# cvae 2: training batches are planned by the agents they carry (max_agents applied), and the log holds the
# latent's diagnostics (unclamped KL, posterior-mean decode against constant velocity, prior spread, z
# sensitivity). goals 2 and evaluate 2: goals drawn by the faster k-means (its float arithmetic settles near-ties
# differently) and a channels-last U-Net; evaluations of models sampled with keys laid out once per rollout.
VERSIONS: Final[dict[str, int]] = {
    "tracks": 1,
    "windows": 1,
    "forces": 3,
    "maps": 1,
    "goal": 2,
    "goals": 2,
    "cvae": 2,
    "dlow": 1,
    "evaluate": 2,
}
# The command that makes each kind, for messages that tell a user how to (re)build one.
COMMANDS: Final[dict[str, str]] = {
    "tracks": "fftool ingest",
    "windows": "fftool ingest",
    "forces": "fftool forces",
    "maps": "fftool maps",
    "goal": "fftool train-goal",
    "goals": "fftool sample-goals",
    "cvae": "fftool train-cvae",
    "dlow": "fftool train-dlow",
    "evaluate": "fftool evaluate",
}

# --- tracks artifact ------------------------------------------------------------------------------
TRACKS_FILE: Final = "tracks.parquet"
TRACKS_SCHEMA: Final = pa.schema(
    [
        pa.field("source", pa.dictionary(pa.int8(), pa.string()), nullable=False),  # e.g. biwi_eth
        pa.field("split", pa.dictionary(pa.int8(), pa.string()), nullable=False),  # all | train | val
        pa.field("frame_id", pa.int64(), nullable=False),  # as in the raw file
        pa.field("step", pa.int64(), nullable=False),  # frame_id // frame_stride
        pa.field("ped_id", pa.int64(), nullable=False),
        pa.field("x", pa.float64(), nullable=False),  # metres
        pa.field("y", pa.float64(), nullable=False),  # metres
    ]
)

# --- windows artifact -----------------------------------------------------------------------------
# windows.parquet: one row per window (a current frame t0 with at least one valid agent) of each
# benchmark part. The window covers steps first_step .. first_step + window_len - 1 of the raw file
# (source, split); t0_step = first_step + obs_len - 1 is the last observed step. Every pedestrian
# present at a step of the window (the neighbours) is found in tracks by (source, split, step).
WINDOWS_FILE: Final = "windows.parquet"
WINDOWS_SCHEMA: Final = pa.schema(
    [
        pa.field("benchmark", pa.dictionary(pa.int8(), pa.string()), nullable=False),
        pa.field("part", pa.dictionary(pa.int8(), pa.string()), nullable=False),  # train | val | test
        pa.field("window_id", pa.int64(), nullable=False),  # 0.. within (benchmark, part)
        pa.field("source", pa.dictionary(pa.int8(), pa.string()), nullable=False),
        pa.field("split", pa.dictionary(pa.int8(), pa.string()), nullable=False),
        pa.field("first_step", pa.int64(), nullable=False),
        pa.field("t0_step", pa.int64(), nullable=False),
        pa.field("t0_frame_id", pa.int64(), nullable=False),
        pa.field("n_agents", pa.int32(), nullable=False),  # valid agents (present at all steps)
        pa.field("n_present", pa.int32(), nullable=False),  # pedestrians present at any step
    ]
)

# agent_windows.parquet: one row per valid agent-window, positions at all window_len steps,
# laid out step-major: xy[2*t], xy[2*t + 1] = x, y at step first_step + t.
AGENT_WINDOWS_FILE: Final = "agent_windows.parquet"


def agent_windows_schema(window_len: int) -> pa.Schema:
    return pa.schema(
        [
            pa.field("benchmark", pa.dictionary(pa.int8(), pa.string()), nullable=False),
            pa.field("part", pa.dictionary(pa.int8(), pa.string()), nullable=False),
            pa.field("window_id", pa.int64(), nullable=False),
            pa.field("ped_id", pa.int64(), nullable=False),
            pa.field("xy", pa.list_(pa.float64(), 2 * window_len), nullable=False),
        ]
    )


# --- forces artifact ------------------------------------------------------------------------------
# Row i of every array below belongs to row i of index.parquet, which repeats the (benchmark, part,
# window_id, ped_id) keys of agent_windows.parquet in the same order. Arrays are .npy files, so
# training can memory-map them (np.load(path, mmap_mode="r")).
FORCES_INDEX_FILE: Final = "index.parquet"
FORCES_ARRAYS: Final = {
    "f_dr": "f_dr.npy",  # (M, L, 2) float32 driving force, N/kg = m/s^2
    "f_re": "f_re.npy",  # (M, L, 2) float32 repulsive force (field-of-view weighted, groups removed)
    "velocity": "velocity.npy",  # (M, L, 2) float32 m/s, causal finite differences
    "goal": "goal.npy",  # (M, 2) float32 the goal used: the ground-truth position at the last step
    "speed0": "speed0.npy",  # (M, L) float32 desired speed v0
    "group_id": "group_id.npy",  # (M,) int32 window-local group (smallest member slot), -1 alone
}

# --- maps artifact --------------------------------------------------------------------------------
# One (C, H, W) float32 raster per scene, `<scene>.npy`; cell [i, j] covers world
# x in [x0 + j·res, x0 + (j+1)·res), y in [y0 + i·res, y0 + (i+1)·res) (row index grows with y).
# transforms.json: {scene: {"origin_x_m", "origin_y_m", "resolution_m", "width", "height"}} and the
# channel names. A source without geometry (uni_examples) has no raster: its crops are all zero.
MAPS_TRANSFORMS_FILE: Final = "transforms.json"


def map_file(scene: str) -> str:
    return f"{scene}.npy"


def map_check_file(scene: str) -> str:
    return f"{scene}_check.png"


# --- goals artifact -------------------------------------------------------------------------------
# goals.npy (M, K, 2) float32 world goals, the goal map's mode first; row i belongs to row i of
# index.parquet (benchmark, part, window_id, ped_id), which follows agent_windows.parquet order
# within each part. cv_goals.npy: the constant-velocity reference, same layout.
GOALS_INDEX_FILE: Final = "index.parquet"
GOALS_FILE: Final = "goals.npy"
CV_GOALS_FILE: Final = "cv_goals.npy"

# --- goal artifact (a trained goal U-Net) -------------------------------------------------------------
GOAL_MODEL_FILE: Final = "model.pt"  # {"state_dict", "in_channels", "config", "benchmark", "best_epoch"}
GOAL_LOG_FILE: Final = "log.csv"  # one row per epoch: every loss term and the validation goal-FDE

# --- cvae artifact (a trained ForceFormer/AgentFormer CVAE) ---------------------------------------------
CVAE_MODEL_FILE: Final = "model.pt"  # {"state_dict", "config", "forces_config", "benchmark", "best_epoch", ...}
CVAE_LOG_FILE: Final = "log.csv"  # one row per epoch: every loss term, validation minADE/minFDE
TENSORBOARD_DIR: Final = "tensorboard"  # the same per-epoch rows as TensorBoard event files

# --- dlow artifact (AgentFormer's DLow sampler over a trained cvae) --------------------------------------
DLOW_MODEL_FILE: Final = "model.pt"  # {"state_dict", "d_model", "z_dim", "k", "hidden", "config", "best_epoch", ...}
DLOW_LOG_FILE: Final = "log.csv"  # one row per epoch: every loss term, validation minADE/minFDE of the K codes

# --- evaluate artifact (one predictor scored on one benchmark part) ------------------------------------
# predictions.parquet: one row per valid agent-window in agent_windows order: window_id, ped_id,
# agent_row, n_agents, per-agent min_ade/min_fde/best_k/collisions/joint_collisions, goal (K·2: each
# sample's goal; the last observed position for predictors that read none) and pred (K·T·2,
# sample-major) in world metres. The manifest holds the summary metrics and definitions.
PREDICTIONS_FILE: Final = "predictions.parquet"
