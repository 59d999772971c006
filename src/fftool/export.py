"""A trained predictor as ONNX graphs, for a planner that cannot load a pickled torch module.

`fftool export cpu/zara1/dr --out zara1_dr/` writes `model.onnx` (the CVAE and how it gets its K codes), for a
goal variant `model_one_goal.onnx` beside it, and `manifest.json` (what each graph takes and gives, in which
units, and the fingerprints it came from). A graph takes one scene (a window of A agents, any A) at a time, and
what the torch path computes before the network:

- `past` (1, A, obs_len, 2) float32, world metres; `agent_mask` (1, A) bool (padded slots are ignored);
- goal variants, model.onnx: `goals` (1, K, A, 2) float32, sample k steering toward goal k (the goals a goal
  U-Net draws); model_one_goal.onnx: `goal` (1, A, 2), each agent's known goal, every sample toward it. The two
  are the torch path's two cases (`Model.predict` with goals per sample or per agent): with a known goal the
  samples take the codes the model draws for one goal (its prior's draws or DLow codes), which a model that
  decodes each of K goals from its prior's mean (`evaluate.fair_code`) does not, so repeating a goal K times in
  model.onnx is not the same;
- dr and re: `speed0` (1, A) float32, each agent's desired speed (m/s); re: `group` (1, A) int64, window-local
  group ids (-1 alone): `learning.observed.desired_speed_and_groups` computes both from `past` as the torch
  path does (the observed mean speed; DBSCAN groups);
- a graph whose codes are prior draws (no DLow sampler, no mean codes): `noise` (1, K, A, Z) float32, standard
  normal draws, code = prior mean + prior std · noise. The random draws stay on the host, so the graph is
  deterministic: fftool draws them as the torch path does (`torch.randn` from the seeded generator), so its
  futures equal the torch path's; any other N(0, 1) source gives other, equally valid samples.

The manifest's `codes` (and `one_goal.codes`) says how each graph gets its K codes: a DLow sampler's, the prior's
mean per goal, or prior draws (the only ones that take `noise`).

Outputs, world metres, float32: `futures` (1, K, A, pred_len, 2), and `most_likely` (1, A, pred_len, 2), the one
future a planner may want (`fftool.api.Model.most_likely`: the prior's mean code toward goal 1, decoded in the same
rollout as one more code or window; sample 1 itself where the model decodes each goal from that mean). A goal
variant exported with its goal U-Net also gets `goal_unet.onnx`: `past` (A, obs_len, 2) float32 metres in, each
agent's goal map out (`logits` (A, S, S) over its crop, the crop's `centre` (A, 2) and `rotation` (A, 2, 2)); the
sampling from those maps (TTST's draws and k-means, `fftool.science.heatmaps.sample_goals`) stays on the host, for
the same reason; the manifest's `goal_unet` block has its settings and the cell-to-world formula.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fftool import __version__
from fftool.errors import UsageError
from fftool.learning.batches import SceneBatch
from fftool.outputs import Kind, check_output, replacing_folder
from fftool.variants import SPECS, reads_goal

ONNX_FILE = "model.onnx"
ONE_GOAL_ONNX_FILE = "model_one_goal.onnx"
GOAL_ONNX_FILE = "goal_unet.onnx"
MANIFEST_FILE = "manifest.json"
OPSET = 18
MAX_AGENTS = 4096  # agents in one scene the graph takes
# How an exported graph gets its K codes (the manifest's "codes"); only prior draws take `noise`.
DLOW_CODES, MEAN_CODES, PRIOR_DRAWS = "DLow sampler", "prior mean per goal", "prior draws: mean + std · noise"


def input_names(variant: str, codes: str, one_goal: bool = False) -> list[str]:
    """The graph's inputs, in order, for a CVAE variant whose codes come as `codes` says; one_goal: the graph of a
    goal variant that takes one known goal per agent (`goal`) instead of one per sample (`goals`)."""
    names = ["past", "agent_mask"]
    names += [("goal" if one_goal else "goals")] if reads_goal(variant) else []
    names += ["speed0"] if SPECS[variant].uses_forces else []
    names += ["group"] if variant == "re" else []
    names += ["noise"] if codes == PRIOR_DRAWS else []
    return names


def protocol_of(variant: str, one_goal: bool) -> str:
    """The goal protocol a graph decodes under: sample k toward goal k (fair) for a goal variant's K goals; one
    goal per agent for every sample, as the torch path decodes known goals (oracle), otherwise."""
    return "fair" if reads_goal(variant) and not one_goal else "oracle"


def codes_of(model: Any, protocol: str) -> str:
    """How `model` (an fftool.api.Model) gets its K codes under `protocol` in an exported graph."""
    if model.mean_codes(protocol):
        return MEAN_CODES
    return DLOW_CODES if model.sampler is not None else PRIOR_DRAWS


class _Graph(torch.nn.Module):
    """The torch path of `Model.predict` from its padded batch on, as one module of tensors in and out; one_goal:
    a goal variant's path for one known goal per agent (`goal`), else for one goal per sample (`goals`)."""

    def __init__(self, model: Any, one_goal: bool = False) -> None:  # an fftool.api.Model
        super().__init__()
        self.net, self.sampler = model.trained.model, model.sampler
        k = model.trained.config.k if model.sampler is None else model.sampler.k
        protocol = protocol_of(model.variant, one_goal)
        self.one_goal, self.codes = one_goal, codes_of(model, protocol)
        self.predictor = model.predictor(k, 0, protocol)
        self.variant, self.obs_len, self.pred_len, self.k = model.variant, model.obs_len, model.pred_len, k
        self.z_dim = model.trained.config.z_dim

    def forward(
        self,
        past: torch.Tensor,
        agent_mask: torch.Tensor,
        goals: torch.Tensor | None = None,
        speed0: torch.Tensor | None = None,
        group: torch.Tensor | None = None,
        noise: torch.Tensor | None = None,
        goal: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        B, A, T, _ = past.shape
        if goal is not None:  # every sample of an agent toward its one goal
            goals = goal[:, None].expand(-1, self.k, -1, -1)
        past = torch.where(agent_mask[:, :, None, None], past, torch.zeros_like(past))
        xy = torch.cat([past, past.new_zeros(B, A, self.pred_len, 2)], 2)
        zeros = torch.zeros_like(xy)
        speed0 = past.new_zeros(B, A) if speed0 is None else speed0
        group = torch.full((B, A), -1, dtype=torch.long, device=past.device) if group is None else group
        batch = SceneBatch(xy, agent_mask, zeros, zeros, speed0, group, torch.zeros_like(group))
        goals = past[:, None, :, T - 1].expand(-1, self.k, -1, -1) if goals is None else goals
        noise = None if noise is None else noise.reshape(B * self.k, A, self.z_dim)
        futures, most_likely = self.predictor.draw(batch, goals, with_most_likely=True, noise=noise)
        assert most_likely is not None
        return futures, most_likely


class _GoalGraph(torch.nn.Module):
    """`GoalSampler.maps`, the goal U-Net's part of drawing goals, as one module of tensors in and out."""

    def __init__(self, goal_sampler: Any, pred_len: int) -> None:  # an fftool.api.GoalSampler
        super().__init__()
        self.net, self.goal_sampler, self.pred_len = goal_sampler.net, goal_sampler, pred_len

    def forward(self, past: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return self.goal_sampler.maps(past, self.pred_len)


def example_inputs(
    variant: str, codes: str, k: int, obs_len: int, z_dim: int, one_goal: bool = False, agents: int = 3
) -> dict[str, np.ndarray]:
    """Inputs of the graph's layout: one window (a scene: the graph takes one at a time) of `agents` agents (more
    than one: torch.export fixes a dimension of size 1)."""
    rng = np.random.default_rng(0)
    steps = rng.normal(0.4, 0.05, (1, agents, obs_len, 2)).astype(np.float32)
    past = np.cumsum(steps, 2) + rng.normal(0, 2, (1, agents, 1, 2)).astype(np.float32)
    values = {"past": past, "agent_mask": np.ones((1, agents), bool)}
    values["goal"] = (past[:, :, -1] + 4.0).astype(np.float32)
    values["goals"] = np.repeat(values["goal"][:, None], k, 1)
    values["speed0"] = np.full((1, agents), 1.0, np.float32)
    values["group"] = np.full((1, agents), -1, np.int64)
    values["noise"] = rng.standard_normal((1, k, agents, z_dim)).astype(np.float32)
    return {name: values[name] for name in input_names(variant, codes, one_goal)}


def is_export(folder: Path) -> bool:
    """Whether `folder` holds what `export` writes: a manifest.json whose format names ONNX."""
    try:
        mark = json.loads((folder / MANIFEST_FILE).read_text()).get("format", "")
    except (OSError, ValueError, AttributeError):
        mark = ""
    return str(mark).startswith("ONNX")


def _foreign(folder: Path) -> str | None:
    """What an existing --out holds that is not an earlier export (None: it is one)."""
    ours = {ONNX_FILE, ONE_GOAL_ONNX_FILE, GOAL_ONNX_FILE, MANIFEST_FILE}
    others = sorted(p.name for p in folder.iterdir() if p.name not in ours)
    if others:
        return f"holds files fftool did not write ({', '.join(others[:5])})"
    return None if is_export(folder) else f"its {MANIFEST_FILE} is not an export's"


EXPORT = Kind("an exported model", True, _foreign)


@dataclass(frozen=True)
class Exported:
    folder: Path
    manifest: dict[str, Any]


def export(model: Any, out: Path, source: dict[str, str], goal_sampler: Any = None) -> Exported:
    """Write `model` (an fftool.api.Model) to `out` as model.onnx (+ model_one_goal.onnx for a goal variant) and
    manifest.json, and a goal variant's `goal_sampler` (an fftool.api.GoalSampler) as goal_unet.onnx, built in a
    temporary folder beside it and moved into place whole. source: where it came from (name, ids)."""
    check_output(out, "--out", EXPORT)
    if goal_sampler is not None and not reads_goal(model.variant):
        raise UsageError(f"the {model.variant} variant reads no goal: it is exported without a goal U-Net")
    graphs = [_Graph(model).eval()] + ([_Graph(model, one_goal=True).eval()] if reads_goal(model.variant) else [])
    graph = graphs[0]
    manifest = {
        "fftool": __version__,
        "format": f"ONNX, opset {OPSET}",
        "variant": model.variant,
        "k": graph.k,
        "z_dim": graph.z_dim,
        "obs_len": model.obs_len,
        "pred_len": model.pred_len,
        "step_s": model.step_s,
        "forces": model.trained.forces_config.model_dump() if model.trained.forces_config else None,
        **_graph_manifest(graph),
        "source": source,
    }
    if len(graphs) > 1:
        manifest["one_goal"] = {"file": ONE_GOAL_ONNX_FILE, **_graph_manifest(graphs[1])}
    if goal_sampler is not None:
        manifest["goal_unet"] = _goal_manifest(goal_sampler, model.obs_len)
    with replacing_folder(out) as partial, torch.no_grad():
        for each in graphs:
            _export_graph(each, partial / (ONE_GOAL_ONNX_FILE if each.one_goal else ONNX_FILE))
        if goal_sampler is not None:
            _export_goal_unet(goal_sampler, model.obs_len, model.pred_len, partial / GOAL_ONNX_FILE)
        (partial / MANIFEST_FILE).write_text(json.dumps(manifest, indent=1) + "\n")
    return Exported(out, manifest)


def _graph_manifest(graph: _Graph) -> dict[str, Any]:
    """What one graph takes and gives: how it gets its codes, its inputs and outputs."""
    names = input_names(graph.variant, graph.codes, graph.one_goal)
    return {
        "codes": graph.codes,
        "inputs": {name: _describe(name, graph.obs_len, graph.k, graph.z_dim) for name in names},
        "outputs": {
            "futures": f"(1, {graph.k}, A, {graph.pred_len}, 2) float32, world metres",
            "most_likely": f"(1, A, {graph.pred_len}, 2) float32, world metres, the prior's mean code toward goal 1",
        },
    }


def _export_graph(graph: _Graph, path: Path) -> None:
    """One CVAE graph at `path`, any agent count."""
    example = example_inputs(graph.variant, graph.codes, graph.k, graph.obs_len, graph.z_dim, graph.one_goal)
    agents = torch.export.Dim("A", max=MAX_AGENTS)
    dims = {"past": {1: agents}, "agent_mask": {1: agents}, "goals": {2: agents}, "goal": {1: agents}}
    dims |= {"speed0": {1: agents}, "group": {1: agents}, "noise": {2: agents}}
    torch.onnx.export(
        graph,
        (),
        str(path),
        kwargs={name: torch.as_tensor(value) for name, value in example.items()},
        input_names=list(example),
        output_names=["futures", "most_likely"],
        dynamic_shapes={name: dims[name] for name in example},
        opset_version=OPSET,
        dynamo=True,
        external_data=False,
        verbose=False,
        optimize=False,
    )
    _name_output_dims(path, [[1, graph.k, "A", graph.pred_len, 2], [1, "A", graph.pred_len, 2]])


def _export_goal_unet(goal_sampler: Any, obs_len: int, pred_len: int, path: Path) -> None:
    """goal_unet.onnx: observed paths (A, obs_len, 2) in, goal maps, crop centres and rotations out."""
    past = torch.as_tensor(example_inputs("goal", MEAN_CODES, 1, obs_len, 0)["past"][0])  # (3, obs_len, 2)
    torch.onnx.export(
        _GoalGraph(goal_sampler, pred_len).eval(),
        (past,),
        str(path),
        input_names=["past"],
        output_names=["logits", "centre", "rotation"],
        dynamic_shapes={"past": {0: torch.export.Dim("A", max=MAX_AGENTS)}},
        opset_version=OPSET,
        dynamo=True,
        external_data=False,
        verbose=False,
        optimize=False,
    )
    S = goal_sampler.config.crop_cells
    _name_output_dims(path, [["A", S, S], ["A", 2], ["A", 2, 2]])


def _goal_manifest(goal_sampler: Any, obs_len: int) -> dict[str, Any]:
    """What a host needs to draw goals from goal_unet.onnx's maps."""
    cfg, S = goal_sampler.config, goal_sampler.config.crop_cells
    return {
        "file": GOAL_ONNX_FILE,
        "inputs": {
            "past": f"(A, {obs_len}, 2) float32, world metres, the observed positions (oldest first) of one scene"
            + (": each agent's map reads where the others are and head" if cfg.neighbour_channels else "")
        },
        "outputs": {
            "logits": f"(A, {S}, {S}) float32, each agent's goal map: logit of the goal's cell (row, col)",
            "centre": "(A, 2) float32, world metres, the crop's centre (the last observed position)",
            "rotation": "(A, 2, 2) float32, the crop's orientation R",
        },
        "cells_to_world": f"world = centre + R @ (cell - {S // 2}) * {cfg.resolution_m} for cell = (col, row)",
        "crop_cells": S,
        "resolution_m": cfg.resolution_m,
        "config": cfg.model_dump(mode="json"),
        "sampling": goal_sampler.sampling.model_dump(mode="json"),
        "sampling_method": "goal 1: the mode (argmax refined over (2r+1)² cells, r = mode_radius_cells); the other "
        "K - 1: TTST, k-means centres of `samples` draws from P = sigmoid(logits / temperature) with cells below "
        "threshold · max P dropped (fftool.science.heatmaps.sample_goals)",
    }


def _name_output_dims(path: Path, shapes: list[list[str | int]]) -> None:
    """Write the outputs' shapes into the graph (the exporter's shape inference fixes the agents' dimension at
    the example's, which onnxruntime then warns about on every call)."""
    import onnx

    graph = onnx.load(str(path))
    for output, dims in zip(graph.graph.output, shapes):
        for dim, value in zip(output.type.tensor_type.shape.dim, dims):
            dim.Clear()
            if isinstance(value, str):
                dim.dim_param = value
            else:
                dim.dim_value = value
    onnx.save(graph, str(path))


def _describe(name: str, obs_len: int, k: int, z_dim: int) -> str:
    return {
        "past": f"(1, A, {obs_len}, 2) float32, world metres, the observed positions (oldest first)",
        "agent_mask": "(1, A) bool, real agents (padded slots are ignored)",
        "goals": f"(1, {k}, A, 2) float32, world metres, the goal of each sample",
        "goal": "(1, A, 2) float32, world metres, each agent's known goal: every sample heads to it",
        "speed0": "(1, A) float32, m/s, each agent's desired speed (fftool: learning.observed)",
        "group": "(1, A) int64, window-local group ids, -1 alone (fftool: learning.observed)",
        "noise": f"(1, {k}, A, {z_dim}) float32, standard normal draws: sample k's code is the prior's mean + its "
        "std · noise[:, k] (fftool: torch.randn from the seeded generator)",
    }[name]
