"""Use a trained ForceFormer in your own code: load it once, hand it observed positions, get K futures.

    from fftool.api import load
    model = load("cvae/3f9c2a")                      # an artifact id, its folder, or a shipped model: cpu/zara1/dr
    futures = model.predict(past, agent_mask, k=20)  # (B, A, 8, 2), (B, A) -> (B, K, A, 12, 2)
    path = model.most_likely(past, agent_mask)       # one future per agent for a planner: (B, A, 12, 2)

`predict_tracks` does the same for a table of tracks (time, agent, x, y), as `fftool predict` does.
Both draw through the sampler `evaluate` uses (learning/sampling.py), so a window `evaluate` scored
gets the same numbers here for the same model and seed. Nothing here needs the command line.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple, Protocol

import numpy as np
import pandas as pd
import torch

from fftool import zoo
from fftool.artifacts.store import Artifact, ArtifactStore, check_schema
from fftool.config import EvaluateConfig, FairCode, GoalConfig, GoalsConfig
from fftool.dataset.scenes import PRED_LEN
from fftool.dataset.steps import ObservedWindows, observed_windows, prediction_steps, to_steps
from fftool.errors import FftoolError, InputError, UsageError
from fftool.learning import devices, goal_model
from fftool.learning.batches import SceneBatch, SceneMaps
from fftool.learning.cvae_model import Trained, load_model
from fftool.learning.dlow_model import load_sampler
from fftool.learning.observed import padded_batch, scene_set
from fftool.learning.sampling import Predictor, collect, plan_batches, sample_batches
from fftool.learning.training import generator
from fftool.models.dlow import QNet
from fftool.variants import SPECS, reads_goal


def find_artifact(ref: str | Path, kind: str, root: Path | None = None) -> tuple[ArtifactStore, Artifact]:
    """An artifact of `kind` by id (`cvae/3f9c2a`, under `root` or the default root) or by its folder, checked
    to be that kind at the schema version this fftool reads and its files to be the ones it was built with;
    with its store."""
    store, artifact = ArtifactStore.open(ref, root)
    if artifact.kind != kind:
        raise UsageError(f"{ref}: a {artifact.kind} artifact, expected a {kind} artifact")
    check_schema(artifact, kind)
    store.check_inputs({kind: artifact})
    return store, artifact


def _cvae_and_sampler(
    ref: str | Path, root: Path | None, dlow: str | Path | None
) -> tuple[ArtifactStore, Artifact, Artifact | None, FairCode]:
    """The CVAE artifact `ref` names, its store, and the DLow sampler to draw through: `dlow` when given, else,
    for a shipped model's name, the one its profile evaluates it with, or `ref` itself when it names a DLow
    sampler (its CVAE comes with it, from the same store); with the code a goal decodes with under the fair
    protocol (a shipped model's profile's, else the prior's draws)."""
    fair_code: FairCode = "prior"
    if zoo.is_name(ref):
        bundle = zoo.find(str(ref))
        store, cvae, sampler, fair_code = bundle.store, bundle.cvae, bundle.dlow, bundle.fair_code
    elif dlow is None and ArtifactStore.open(ref, root)[1].kind == "dlow":
        store, sampler = find_artifact(ref, "dlow", root)
        found = store.lookup("cvae", sampler.manifest.sources.get("cvae", ""))
        if found is None:
            raise FftoolError(f"{ref}: the CVAE it was trained over is not in {store.root}")
        cvae = found
        find_artifact(cvae.path, "cvae", root)  # checked as any CVAE named directly
    else:
        store, cvae = find_artifact(ref, "cvae", root)
        sampler = None
    if dlow is not None:
        _, sampler = find_artifact(dlow, "dlow", root)
    if sampler is not None and sampler.manifest.sources.get("cvae") != cvae.fingerprint:
        raise UsageError(f"{dlow}: a DLow sampler trained over another CVAE than {cvae.id}")
    return store, cvae, sampler, fair_code


@dataclass(frozen=True)
class Model:
    """A trained CVAE with the window layout it was trained on."""

    trained: Trained
    obs_len: int
    pred_len: int
    device: torch.device
    sampler: QNet | None = None  # a DLow sampler of this CVAE: its K codes replace the prior's draws
    # kind -> fingerprint of the artifacts it was loaded from (the cvae, and its dlow sampler)
    fingerprints: dict[str, str] = field(default_factory=dict)
    # With K goals per agent (the fair protocol): each goal decoded from a prior draw (or the sampler's code k),
    # or from the prior's mean code (evaluate.fair_code).
    fair_code: FairCode = "prior"

    def mean_codes(self, protocol: str) -> bool:
        """Whether predictions under `protocol` decode each goal from the prior's mean (no sampler, no draws)."""
        return EvaluateConfig(protocol=protocol, fair_code=self.fair_code).mean_codes(self.variant)

    @property
    def variant(self) -> str:
        return self.trained.config.variant

    @property
    def step_s(self) -> float:
        """Seconds per step of the data it was trained on."""
        return float(self.trained.dt_s or 0.4)

    def predictor(self, k: int, seed: int, protocol: str = "oracle", sampled: np.ndarray | None = None) -> Predictor:
        cfg = EvaluateConfig(k=k, seed=seed, protocol=protocol, fair_code=self.fair_code)
        if self.sampler is not None and self.sampler.k != k and not self.mean_codes(protocol):
            raise UsageError(f"this model's DLow sampler draws k = {self.sampler.k} futures per agent, not {k}")
        return Predictor(cfg, self.trained, sampled, self.obs_len, self.pred_len, self.device, self.sampler)

    def predict(
        self, past: np.ndarray, agent_mask: np.ndarray, *, k: int = 20, goals: np.ndarray | None = None, seed: int = 0
    ) -> np.ndarray:
        """K futures (B, K, A, pred_len, 2) in metres for observed positions past (B, A, obs_len, 2).

        agent_mask (B, A) bool marks real agents (padding slots are ignored, whatever they hold). goals: for goal
        variants, (B, A, 2) one goal per agent, or (B, A, K, 2) one per sample. The draws are fixed by `seed`.
        Input a model cannot take is an InputError naming the window, agent and step, before any work.
        """
        check_seed(seed)
        mask, batch = self._batch(past, agent_mask, k, goals)
        if not reads_goal(self.variant):
            predictor = self.predictor(k, seed)
            goals_k = predictor.goals(batch, np.zeros(mask.shape, np.int64))
        elif goals is None:
            raise UsageError(f"the {self.variant} variant steers toward goals: pass goals (B, A, 2) or (B, A, K, 2)")
        else:
            goals_t = torch.as_tensor(np.asarray(goals), dtype=torch.float32, device=self.device)
            per_sample = goals_t.dim() == 4
            predictor = self.predictor(k, seed, "fair" if per_sample else "oracle")
            goals_k = goals_t.transpose(1, 2) if per_sample else goals_t[:, None].expand(-1, k, -1, -1)
        with torch.no_grad():
            return predictor(batch, goals_k).cpu().numpy()

    def _batch(
        self, past: np.ndarray, agent_mask: np.ndarray, k: int, goals: np.ndarray | None
    ) -> tuple[np.ndarray, SceneBatch]:
        """The request checked before any work, as (agent_mask, the padded batch on the model's device)."""
        past, mask = np.asarray(past, dtype=np.float64), np.asarray(agent_mask, dtype=bool)
        if past.ndim != 4 or past.shape[2:] != (self.obs_len, 2) or mask.shape != past.shape[:2]:
            raise UsageError(
                f"expected past (B, A, {self.obs_len}, 2) and agent_mask (B, A), got {past.shape} and {mask.shape}"
            )
        check_request(past, mask, k, self.pred_len)
        past = np.where(mask[:, :, None, None], past, 0.0)  # padding never reaches the model, NaN or not
        if goals is not None:
            check_goals(np.asarray(goals, dtype=np.float64), mask)
        batch = padded_batch(past, mask, self.pred_len, self.trained.forces_config, self.trained.dt_s)
        return mask, batch.to(self.device)

    def most_likely(self, past: np.ndarray, agent_mask: np.ndarray, *, goals: np.ndarray | None = None) -> np.ndarray:
        """One future per agent (B, A, pred_len, 2) in metres, for a planner that wants one: the decoder's path
        from the centre of its prior (the mean code z = μ of p(z | past), not a draw), toward goals (B, A, 2)
        for goal variants. Deterministic. The K samples of `predict` are equally likely draws: the model gives
        them no weights, so the most-likely future is this decoding, not one of the K."""
        mask, batch = self._batch(past, agent_mask, 1, goals)
        if reads_goal(self.variant):
            if goals is None or np.shape(goals) != (*mask.shape, 2):
                raise UsageError(f"the {self.variant} variant steers toward goals: pass goals (B, A, 2)")
            goal = torch.as_tensor(np.asarray(goals), dtype=torch.float32, device=self.device)
        else:
            goal = batch.xy[:, :, self.obs_len - 1]
        with torch.no_grad():
            return (
                self.predictor(1 if self.sampler is None else self.sampler.k, 0).most_likely(batch, goal).cpu().numpy()
            )


# Coordinates beyond this many metres from the origin are no pedestrian scene: a unit or a sentinel value.
MAX_ABS_COORDINATE_M = 1e5
# The most future coordinates one call may return (B · K · A · pred_len · 2 floats: 2 GiB).
MAX_OUTPUT_VALUES = 2**28
# The most memory the agent-aware attention of one window may ask for: K · heads · (agents · obs_len)² floats.
MAX_ATTENTION_BYTES = 2**31


def check_k(k: object, agent_slots: int, pred_len: int) -> None:
    """k must be a whole number ≥ 1 whose futures for `agent_slots` agents fit in memory (MAX_OUTPUT_VALUES)."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise InputError(f"k = {k!r}: expected a whole number of samples per agent, at least 1")
    values = agent_slots * int(k) * pred_len * 2
    if values > MAX_OUTPUT_VALUES:
        raise InputError(
            f"k = {k} for {agent_slots} agent(s) asks for {values:,} future coordinates (at most "
            f"{MAX_OUTPUT_VALUES:,} per call): lower k, or predict fewer agents or times per call"
        )


def check_seed(seed: object) -> None:
    """A seed is a whole number in [0, 2**63): what torch's and numpy's generators take."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) < 2**63:
        raise InputError(f"seed = {seed!r}: expected a whole number from 0 to 2**63 - 1")


def check_request(past: np.ndarray, mask: np.ndarray, k: object, pred_len: int) -> None:
    """Refuse what a model cannot take, naming where: a k that is not a whole number ≥ 1 or asks for more
    futures than fit in memory, a window without agents, a non-finite or absurd coordinate of a real agent."""
    check_k(k, past.shape[0] * past.shape[1], pred_len)
    empty = np.flatnonzero(~mask.any(1))
    if empty.size:
        raise InputError(f"window {empty[0]}: agent_mask marks no agent; give every window at least one")
    bad = mask[:, :, None] & off_limits(past)
    if bad.any():
        b, a, t = (int(i) for i in np.argwhere(bad)[0])
        raise InputError(
            f"window {b}, agent {a}, observed step {t}: position {past[b, a, t].tolist()} is not a finite "
            f"coordinate within ±{MAX_ABS_COORDINATE_M:g} m (mask the agent out, or give its position in metres)"
        )


def off_limits(xy: np.ndarray) -> np.ndarray:
    """(..., 2) -> (...): points that are not finite coordinates within ±MAX_ABS_COORDINATE_M."""
    return ~(np.isfinite(xy) & (np.abs(xy) <= MAX_ABS_COORDINATE_M)).all(-1)


def check_goals(goals: np.ndarray, mask: np.ndarray) -> None:
    """Goals of real agents must be finite coordinates within the same bounds as positions."""
    real = mask if goals.ndim == 3 else mask[:, :, None]
    bad = real & off_limits(goals)
    if bad.any():
        where = ", ".join(str(int(i)) for i in np.argwhere(bad)[0])
        raise InputError(f"goals[{where}]: not a finite coordinate within ±{MAX_ABS_COORDINATE_M:g} m")


def load(
    ref: str | Path, *, root: Path | None = None, device: str | torch.device = "cpu", dlow: str | Path | None = None
) -> Model:
    """A trained CVAE from its artifact id (`cvae/3f9c2a`), folder, or shipped name (`cpu/zara1/dr`, `fftool models
    list`), on `device` (cpu, cuda); with `dlow` (a `dlow` artifact trained over this CVAE) its K futures come from
    AgentFormer's DLow sampler, as they do for a shipped model its profile evaluates through one. A DLow
    sampler's own id (`dlow/8e1b07`) loads it with the CVAE it was trained over."""
    store, artifact, sampler_artifact, fair_code = _cvae_and_sampler(ref, root, dlow)
    chosen = devices.resolve(device)
    trained = load_model(artifact, chosen)
    sampler = None if sampler_artifact is None else load_sampler(sampler_artifact, chosen)
    windows = [a for a in store.chain(artifact) if isinstance(a, Artifact) and a.kind == "windows"]
    stats = windows[0].manifest.stats if windows else {"obs_len": 8, "pred_len": PRED_LEN}
    loaded = {a.kind: a.fingerprint for a in (artifact, sampler_artifact) if a is not None}
    return Model(trained, int(stats["obs_len"]), int(stats["pred_len"]), chosen, sampler, loaded, fair_code)


class DrawsGoals(Protocol):
    """What draws K goals per observed path: a `GoalSampler`, or an export's goal U-Net (fftool.exported)."""

    def sample(
        self, past: np.ndarray, k: int, seed: int, pred_len: int, device: torch.device, window: np.ndarray | None = None
    ) -> np.ndarray: ...


@dataclass(frozen=True)
class GoalSampler:
    """A trained goal U-Net that draws K goals per observed path, without a scene map (its map channels are 0),
    the way its best epoch was chosen (`sampling`, K aside)."""

    net: torch.nn.Module
    config: GoalConfig
    sampling: GoalsConfig
    in_channels: int

    def maps(
        self, obs: torch.Tensor, pred_len: int, others: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The goal maps' logits (M, S, S), crop centres (M, 2) and rotations (M, 2, 2) of observed paths obs
        (M, T, 2) metres: the network's part, which `fftool export` writes as a graph. A goal U-Net that reads
        the other walkers reads `others` (M, N, T, 2; `goal_model.Neighbours`), or else takes the M paths for
        one scene."""
        channels = self.in_channels - goal_model.input_channels(self.config, obs.shape[1], 0)
        blank = SceneMaps(torch.zeros(1, channels, 1, 1), torch.zeros(1, 2), 1.0, ()).to(obs.device)
        scene = torch.zeros(obs.shape[0], dtype=torch.long, device=obs.device)
        if self.config.neighbour_channels and others is None:
            others = goal_model.scene_others(obs)
        return goal_model.goal_map(self.net, obs, scene, blank, self.config, pred_len, others)

    def sample(
        self, past: np.ndarray, k: int, seed: int, pred_len: int, device: torch.device, window: np.ndarray | None = None
    ) -> np.ndarray:
        """(M, K, 2) goals for observed paths past (M, T, 2) of the scenes `window` (M,) (default: one scene)."""
        others = None
        if self.config.neighbour_channels and window is not None:
            others = goal_model.Neighbours.of(past, window).observed(slice(None), past.shape[1]).to(device)
        with torch.no_grad():
            maps = self.maps(torch.as_tensor(past, dtype=torch.float32, device=device), pred_len, others)
            return draw_goals(maps, self.config, self.sampling, k, seed).cpu().numpy()


def draw_goals(
    maps: tuple[torch.Tensor, torch.Tensor, torch.Tensor], cfg: GoalConfig, sampling: GoalsConfig, k: int, seed: int
) -> torch.Tensor:
    """(M, K, 2) world goals drawn from goal maps (`GoalSampler.maps`) with `sampling` and K = k, seeded."""
    logits = maps[0]
    return goal_model.goals_from_map(*maps, cfg, sampling.model_copy(update={"k": k}), generator(seed, logits.device))


def load_goal_sampler(ref: str | Path, *, root: Path | None = None, device: str | torch.device = "cpu") -> GoalSampler:
    """A trained goal U-Net from its artifact id (`goal/3f9c2a`) or folder, or the one shipped with a goal
    variant's model (`cpu/zara1/dr`: its benchmark's)."""
    if zoo.is_name(ref):
        artifact = zoo.find(str(ref)).goal
        if artifact is None:
            raise UsageError(f"{ref}: a variant that reads no goal, shipped without a goal U-Net")
    else:
        _, artifact = find_artifact(ref, "goal", root)
    net, cfg, sampling = goal_model.load_model(artifact, devices.resolve(device))
    first = next(module for module in net.modules() if isinstance(module, torch.nn.Conv2d))
    return GoalSampler(net, cfg, sampling, first.in_channels)


def predict_tracks(
    model: Model,
    tracks: pd.DataFrame,
    *,
    source: Path = Path("<tracks>"),
    at: str | list[float] = "last",
    k: int = 20,
    seed: int = 0,
    goals: Mapping[object, tuple[float, float]] | None = None,
    goal_sampler: DrawsGoals | None = None,
    max_gap_s: float = 1.0,
    most_likely: bool = False,
) -> tuple[pd.DataFrame, list[str]]:
    """K futures for every agent with all observed steps at the prediction time(s), and the warnings.

    tracks: rows (time_s, agent, x, y) as `dataset.trackfiles.read_tracks` gives. at: "last" (the file's
    last time), "all" (every time an agent has a full history) or times in seconds. goals: one (x, y) per
    agent id, or goal_sampler: K goals per agent from a goal U-Net (goal variants need one of them).
    most_likely: instead of the K samples, the one most-likely future (`Model.most_likely`), as sample 0.
    Returns one row per (time, agent, sample, step): time_s, agent, sample, step, x, y, goal_x, goal_y.
    """
    if not isinstance(at, str) and not np.isfinite(np.asarray(at, dtype=np.float64)).all():
        raise InputError(f"prediction times {at}: expected finite seconds")
    steps = to_steps(source, tracks, model.step_s, max_gap_s)
    found = observed_windows(source, steps, model.obs_len, prediction_steps(steps, at))
    labels = steps.labels[found.agent]
    drawn = draw_futures(
        model, found, labels, k=k, seed=seed, goals=goals, goal_sampler=goal_sampler, most_likely=most_likely
    )
    goal, pred = (drawn.goals[:, :1], drawn.most_likely[:, None]) if most_likely else (drawn.goals, drawn.futures)
    return futures_table(steps.time_of(found.t0_step[found.window]), labels, goal, pred), steps.warnings


class Drawn(NamedTuple):
    """What `draw_futures` gives for M agent-windows."""

    goals: np.ndarray  # (M, K, 2) the goal each sample steered toward (the last position for goal-free variants)
    futures: np.ndarray  # (M, K, pred_len, 2) metres
    most_likely: np.ndarray  # (M, pred_len, 2) the prior's mean code decoded toward goal 1; (0,) when not asked for


def draw_futures(
    model: Model,
    found: ObservedWindows,
    labels: np.ndarray,
    *,
    k: int,
    seed: int,
    goals: Mapping[object, tuple[float, float]] | None,
    goal_sampler: DrawsGoals | None,
    most_likely: bool = True,
) -> Drawn:
    """The goals, K futures and most-likely future of the observed agent-windows `found`, whose agent ids are
    `labels` (M,): the one drawing path of `predict_tracks` and `OnlinePredictor`. most_likely: decode that one
    future too (in the same rollout as the K: a few more tokens; `predict` asks for it only with --most-likely)."""
    check_k(k, len(found.xy), model.pred_len)
    check_seed(seed)
    crowd = int(np.bincount(found.window).max()) if len(found.window) else 0
    need = int(k) * model.trained.config.n_heads * (crowd * model.obs_len) ** 2 * 4
    if need > MAX_ATTENTION_BYTES:
        raise InputError(
            f"{crowd} agents at one time with k = {k} ask about {need / 2**30:.0f} GiB for the model's attention (at "
            f"most {MAX_ATTENTION_BYTES / 2**30:.0f} GiB): predict fewer agents at a time, or lower k"
        )
    far = off_limits(found.xy).any(1)
    if far.any():
        m = int(np.argmax(far))
        raise InputError(
            f"agent {labels[m]}: observed positions {found.xy[m][off_limits(found.xy[m])][0].tolist()} are not "
            f"finite coordinates within ±{MAX_ABS_COORDINATE_M:g} m (positions in metres?)"
        )
    for label, goal in (goals or {}).items():
        try:
            point = np.asarray(goal, dtype=np.float64).reshape(2)
        except (TypeError, ValueError):
            point = np.full(2, np.nan)
        if off_limits(point[None]).any():
            raise InputError(f"agent {label}: goal {goal!r} is not an (x, y) within ±{MAX_ABS_COORDINATE_M:g} m")
    trained = model.trained
    groups = "group_id" in SPECS[model.variant].sampling_reads
    scenes = scene_set(found.xy, found.window, found.agent, model.pred_len, trained.forces_config, trained.dt_s, groups)
    predictor = model.predictor(k, seed)
    goals_of = predictor.goals
    if reads_goal(model.variant):
        chosen, all_passed = goals_per_sample(
            model.variant, labels, found.xy, goals, goal_sampler, k=k, seed=seed, pred_len=model.pred_len,
            device=model.device, window=found.window,
        )  # fmt: skip
        if all_passed:  # every agent's goal is known: one goal for all K samples
            given = chosen[:, 0]

            def goals_of(batch: object, positions: np.ndarray) -> torch.Tensor:
                known = torch.as_tensor(given[np.where(positions >= 0, positions, 0)], dtype=torch.float32)
                return known.to(model.device)[:, None].expand(-1, k, -1, -1)

        else:  # sample k decodes goal k
            predictor = model.predictor(k, seed, "fair", chosen)
            goals_of = predictor.goals
    plan = plan_batches(scenes, predictor.cfg)
    columns = collect(
        sample_batches(predictor, scenes, plan, goals_of, model.device, with_most_likely=most_likely),
        lambda batch, goals_k, futures: (
            {"goal": goals_k.transpose(1, 2), "pred": futures[:, :k].transpose(1, 2)}
            | ({"likely": futures[:, k]} if most_likely else {})
        ),
    )
    return Drawn(columns["goal"], columns["pred"], columns.get("likely", np.zeros(0)))


def goals_per_sample(
    variant: str,
    labels: np.ndarray,
    past: np.ndarray,
    goals: Mapping[object, tuple[float, float]] | None,
    goal_sampler: DrawsGoals | None,
    *,
    k: int,
    seed: int,
    pred_len: int,
    device: torch.device,
    window: np.ndarray | None = None,
) -> tuple[np.ndarray, bool]:
    """(M, K, 2) the goal each of K samples of a goal variant steers toward, for agents `labels` (M,) observed
    at `past` (M, T, 2) in the scenes `window` (M,) (default: one scene), and whether every agent's goal was
    passed. A passed goal comes first (all K samples head to it); the others get the goal sampler's K goals
    (sample k, goal k), or an error names them."""
    passed = np.array([goals is not None and label in goals for label in labels], bool)
    given = np.array([goals[label] if ok else (np.nan, np.nan) for label, ok in zip(labels, passed)], np.float64)
    given = given.reshape(len(labels), 2)
    if passed.all():
        return np.repeat(given[:, None], k, 1), True
    if goal_sampler is not None:
        sampled = goal_sampler.sample(past, k, seed, pred_len, device, window)
        sampled[passed] = given[passed, None].astype(sampled.dtype)
        return sampled, False
    if goals is not None:
        missing = list(dict.fromkeys(labels[~passed].tolist()))[:5]
        raise FftoolError(f"no goal given for agent(s) {', '.join(map(str, missing))}")
    raise UsageError(f"the {variant} variant steers toward goals: give goals or a goal U-Net")


def futures_table(t0_s: np.ndarray, labels: np.ndarray, goal: np.ndarray, pred: np.ndarray) -> pd.DataFrame:
    """Long format: one row per (agent-window, sample, future step)."""
    M, K, T, _ = pred.shape
    per_row = lambda a: np.repeat(a, K * T)  # noqa: E731
    return pd.DataFrame(
        {
            "time_s": per_row(t0_s),
            "agent": per_row(labels),
            "sample": np.tile(np.repeat(np.arange(K), T), M),
            "step": np.tile(np.arange(1, T + 1), M * K),
            "x": pred[..., 0].reshape(-1),
            "y": pred[..., 1].reshape(-1),
            "goal_x": np.repeat(goal[..., 0].reshape(-1), T),
            "goal_y": np.repeat(goal[..., 1].reshape(-1), T),
        }
    )
