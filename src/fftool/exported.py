"""An `fftool export` folder run by onnxruntime: the K futures and the most-likely future of one scene per call, as
the torch path gives them within 1e-4 m, and a goal variant's goals from its exported goal U-Net.
`fftool.online.OnlinePredictor` runs on one when given its folder; a planner's own code needs only onnxruntime and
the manifest (docs/api.md)."""

from __future__ import annotations

import importlib.util
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from pydantic import ValidationError

from fftool.api import draw_goals
from fftool.config import ForcesConfig, GoalConfig, GoalsConfig
from fftool.errors import InputError, UsageError
from fftool.export import GOAL_ONNX_FILE, MANIFEST_FILE, ONE_GOAL_ONNX_FILE, ONNX_FILE, input_names, is_export
from fftool.learning.observed import desired_speed_and_groups
from fftool.learning.training import generator
from fftool.variants import SPECS


@dataclass(frozen=True)
class ExportedGoalSampler:
    """An exported goal U-Net: its graph draws the goal maps (onnxruntime), the host samples goals from them as
    `fftool.api.GoalSampler` does (the same seeded draws)."""

    session: Any  # onnxruntime.InferenceSession of goal_unet.onnx
    config: GoalConfig
    sampling: GoalsConfig

    def sample(
        self, past: np.ndarray, k: int, seed: int, pred_len: int, device: torch.device, window: np.ndarray | None = None
    ) -> np.ndarray:
        """(M, K, 2) goals for observed paths past (M, T, 2) of the scenes `window` (M,) (default: one scene;
        pred_len is the graph's own). The graph takes one scene at a time: a goal U-Net that reads the other
        walkers reads every other path of the call."""
        past = np.asarray(past, np.float32)
        scenes = [np.arange(len(past))]
        if self.config.neighbour_channels and window is not None:
            scenes = [np.flatnonzero(window == w) for w in np.unique(window)]
        parts = [self.session.run(None, {"past": past[rows]}) for rows in scenes]
        order = np.argsort(np.concatenate(scenes), kind="stable")
        maps = tuple(torch.as_tensor(np.concatenate(arrays)[order]) for arrays in zip(*parts))
        return draw_goals(maps, self.config, self.sampling, k, seed).numpy()


@dataclass(frozen=True)
class ExportedModel:
    """An exported predictor: its manifest's facts and onnxruntime sessions of its graphs (CPU)."""

    folder: Path
    manifest: dict[str, Any]
    session: Any  # onnxruntime.InferenceSession of model.onnx
    one_goal_session: Any  # a goal variant's model_one_goal.onnx (one known goal per agent); None otherwise
    forces_config: ForcesConfig | None
    goal_sampler: ExportedGoalSampler | None  # a goal variant exported with its goal U-Net
    device = torch.device("cpu")  # where a goal sampler beside it runs

    @classmethod
    def load(cls, folder: str | Path, threads: int | None = None) -> ExportedModel:
        """The export in `folder`, or an error naming what is missing (UsageError) or damaged (InputError);
        threads: onnxruntime's threads per graph (default: its own choice, one per core)."""
        folder = Path(folder)
        if not is_export(folder):
            raise UsageError(f"{folder}: not a folder `fftool export` wrote ({MANIFEST_FILE} of an ONNX export)")
        if importlib.util.find_spec("onnxruntime") is None:
            raise UsageError('running an exported model needs onnxruntime: pip install "fftool[onnx]"')
        where = folder / MANIFEST_FILE
        manifest = json.loads(where.read_text())
        missing = [key for key in ("variant", "k", "obs_len", "pred_len", "step_s", "inputs") if key not in manifest]
        if missing:
            raise InputError(f"{where}: missing {missing}")
        if manifest["variant"] not in SPECS:
            raise InputError(f"{where}: variant {manifest['variant']!r} is none of {sorted(SPECS)}")
        _check_graph(where, manifest, one_goal=False)
        if SPECS[manifest["variant"]].reads_goal:
            _check_graph(where, manifest, one_goal=True)
        try:
            forces = ForcesConfig.model_validate(manifest["forces"]) if manifest.get("forces") else None
        except ValidationError as exc:
            first = exc.errors()[0]
            raise InputError(f"{where}: forces.{'.'.join(map(str, first['loc']))}: {first['msg']}") from None
        goal_sampler = None
        if manifest.get("goal_unet"):
            try:
                goal_cfg = GoalConfig.model_validate(manifest["goal_unet"]["config"])
                sampling = GoalsConfig.model_validate(manifest["goal_unet"]["sampling"])
            except (ValidationError, KeyError, TypeError) as exc:
                raise InputError(f"{where}: goal_unet: expected its config and sampling ({exc})") from None
            goal_sampler = ExportedGoalSampler(_session(folder / GOAL_ONNX_FILE, threads), goal_cfg, sampling)
        one_goal = _session(folder / ONE_GOAL_ONNX_FILE, threads) if manifest.get("one_goal") else None
        return cls(folder, manifest, _session(folder / ONNX_FILE, threads), one_goal, forces, goal_sampler)

    @property
    def variant(self) -> str:
        return str(self.manifest["variant"])

    @property
    def k(self) -> int:
        return int(self.manifest["k"])

    @property
    def obs_len(self) -> int:
        return int(self.manifest["obs_len"])

    @property
    def pred_len(self) -> int:
        return int(self.manifest["pred_len"])

    @property
    def step_s(self) -> float:
        return float(self.manifest["step_s"])

    def draw(self, past: np.ndarray, goals: np.ndarray | None = None, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """The K futures (M, K, pred_len, 2) and the most-likely future (M, pred_len, 2), metres, of the M agents
        of one scene observed at past (M, obs_len, 2) metres. Goal variants: goals (M, K, 2), sample k steering
        toward goal k (model.onnx), or (M, 2), each agent's known goal for all K samples (model_one_goal.onnx),
        as `Model.predict` takes them. A model drawing from its prior gets the standard normal draws the torch
        path makes with `seed`, so both give the same futures."""
        past = np.asarray(past, np.float32)[None]
        mask = np.ones(past.shape[:2], bool)
        known = goals is not None and np.ndim(goals) == 2
        session, described = (
            (self.one_goal_session, self.manifest["one_goal"]) if known else (self.session, self.manifest)
        )
        inputs = described["inputs"]
        groups = "group" in inputs  # as the torch path: DBSCAN only for a variant that reads groups
        speed0, group = desired_speed_and_groups(past, mask, self.forces_config, self.step_s, groups)
        values = {"past": past, "agent_mask": mask, "speed0": speed0.astype(np.float32), "group": group}
        if known:
            values["goal"] = np.asarray(goals, np.float32)[None]
        elif goals is not None:
            values["goals"] = np.asarray(goals, np.float32).transpose(1, 0, 2)[None]
        if "noise" in inputs:
            shape = (self.k, past.shape[1], int(self.manifest["z_dim"]))  # the torch path's (K windows, A, Z)
            values["noise"] = torch.randn(shape, generator=generator(seed, self.device)).numpy()[None]
        futures, most_likely = session.run(None, {name: values[name] for name in inputs})
        return futures[0].transpose(1, 0, 2, 3), most_likely[0]


def _check_graph(where: Path, manifest: dict[str, Any], one_goal: bool) -> None:
    """One graph's block of the manifest (`export._graph_manifest`; a goal variant's known-goal graph under
    `one_goal`): its inputs those of its variant and codes."""
    described, prefix = (manifest.get("one_goal"), "one_goal.") if one_goal else (manifest, "")
    if not isinstance(described, dict):
        raise InputError(f"{where}: one_goal: expected the known-goal graph (an earlier fftool's export: export again)")
    if not isinstance(described.get("inputs"), dict):
        raise InputError(f"{where}: {prefix}inputs: expected the graph's inputs")
    expected = input_names(manifest["variant"], str(described.get("codes")), one_goal)
    if "noise" in expected and not isinstance(manifest.get("z_dim"), int):
        raise InputError(f"{where}: z_dim: expected the codes' size (a whole number) for the noise input")
    if list(described["inputs"]) != expected:
        raise InputError(f"{where}: {prefix}inputs {list(described['inputs'])}, expected {expected} for its variant")
    if list(described.get("outputs", {})) != ["futures", "most_likely"]:
        raise InputError(
            f"{where}: {prefix}outputs: expected futures and most_likely (an earlier fftool's export: export again)"
        )


def _session(path: Path, threads: int | None) -> Any:
    """An onnxruntime session of the graph at `path` (CPU), or an InputError naming it. Its log shows errors
    only: loading a graph otherwise prints a line for each cast it cannot fold ahead of time."""
    import onnxruntime

    options = onnxruntime.SessionOptions()
    options.log_severity_level = 3
    if threads is not None:
        options.intra_op_num_threads = options.inter_op_num_threads = threads
    try:
        return onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime's own errors: a missing or damaged graph
        raise InputError(f"{path}: not a graph onnxruntime can load ({exc})") from None
