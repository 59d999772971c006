"""Sample K goals per valid agent-window from a trained goal U-Net, and score the goal module alone.

Reads: goal (the model), windows, maps. Writes: `goals/<fp>/goals.npy` (M, K, 2), `cv_goals.npy`
(the constant-velocity reference, same layout) and index.parquet. Run:
`fftool sample-goals --benchmarks zara1`. The manifest holds goal-FDE@K and FDE@1 per part for both.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Final

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import torch

from fftool.artifacts.schema import COMMANDS, CV_GOALS_FILE, GOALS_FILE, GOALS_INDEX_FILE, VERSIONS
from fftool.artifacts.store import Artifact
from fftool.config import GoalsConfig, PipelineConfig
from fftool.learning.batches import load_agent_windows
from fftool.learning.goal_model import goal_batches, load_model
from fftool.learning.protocols import constant_velocity
from fftool.learning.scene_prior import goal_scene_index, load_goal_scenes
from fftool.learning.training import generator
from fftool.science.metrics import goal_fde
from fftool.stages.contract import Reads, Stage, StageContext

NAME: Final = "goals"


def sample(
    cfg: GoalsConfig,
    benchmark: str,
    goal: Artifact,
    windows: Artifact,
    maps: Artifact,
    out_dir: Path,
    device: torch.device,
    on_progress: Callable[[str, int, int], None] | None = None,
) -> dict[str, Any]:
    """Goals for every valid agent-window of the configured parts; FDE of the module and the CV reference.

    Args:
        cfg: the `goals` section. benchmark: whose parts to sample.
        goal, windows, maps: input artifacts. out_dir: the build folder.
        device: torch device. on_progress: called with (part, done, total).
    """
    model, goal_cfg, _ = load_model(goal, device)
    scene_maps = load_goal_scenes(maps, windows, benchmark, goal_cfg).to(device)
    obs_len = int(windows.manifest.stats["obs_len"])
    pred_len = int(windows.manifest.stats["pred_len"])
    gen = generator(cfg.seed, device)
    all_goals, all_cv, index, parts = [], [], [], {}
    for part in cfg.parts:
        data = load_agent_windows(windows, benchmark, part)
        scene = goal_scene_index(scene_maps, data, goal_cfg, cross_fit=False)
        fde = {"goal_k": [], "goal_1": [], "cv_1": [], "cv_k": []}
        batches = goal_batches(model, data, scene, scene_maps, goal_cfg, cfg, gen, obs_len, pred_len, device, 256)
        for done, xy, goals in batches:
            obs, truth = xy[:, :obs_len], xy[:, -1]
            cv = constant_velocity(obs[:, None], pred_len, cfg.k, cfg.cv_angle_std_deg, cfg.cv_speed_std, gen)
            cv = cv[:, :, 0, -1]  # (B, K, 2): each sample's end point
            for prefix, values in (("goal", goals), ("cv", cv)):
                k, one = goal_fde(values, truth)
                fde[f"{prefix}_k"].append(k)
                fde[f"{prefix}_1"].append(one)
            all_goals.append(goals.cpu().numpy())
            all_cv.append(cv.cpu().numpy())
            if on_progress:
                on_progress(part, done, len(data))
        index.append(
            pa.table(
                {
                    "benchmark": [benchmark] * len(data),
                    "part": [part] * len(data),
                    "window_id": data.window_id,
                    "ped_id": data.ped_id,
                }
            )
        )
        means = {name: float(torch.cat(values).mean()) if values else float("nan") for name, values in fde.items()}
        parts[part] = {
            "agent_windows": len(data),
            f"goal_fde@{cfg.k}_m": means["goal_k"],
            "goal_fde@1_m": means["goal_1"],
            "cv_fde@1_m": means["cv_1"],
            f"cv_fde@{cfg.k}_m": means["cv_k"],
        }
    np.save(out_dir / GOALS_FILE, np.concatenate(all_goals).astype(np.float32))
    np.save(out_dir / CV_GOALS_FILE, np.concatenate(all_cv).astype(np.float32))
    pq.write_table(pa.concat_tables(index), out_dir / GOALS_INDEX_FILE)
    return {"benchmark": benchmark, "k": cfg.k, "method": cfg.method, "device": str(device), "parts": parts}


def build(cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: StageContext) -> dict[str, Any]:
    """The stage contract: K goals per agent-window of one benchmark."""
    upstream = (inputs["goal"], inputs["windows"], inputs["maps"])
    return sample(cfg.goals, ctx.need_benchmark(), *upstream, ctx.dir, ctx.device(), on_progress=ctx.on_progress)


STAGE = Stage(
    NAME,
    VERSIONS[NAME],
    COMMANDS[NAME],
    label="sample goals",
    declare=lambda cfg: Reads(params=("goals.*",), artifacts={"goal": None, "windows": None, "maps": None}),
    build=build,
    section="goals",
    per_benchmark=True,
)
