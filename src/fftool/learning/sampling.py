"""Drawing K futures from a trained predictor: the one sampling path of `evaluate`, `predict` and the API.

`Predictor` turns a padded `SceneBatch` and per-sample goals into K world-frame futures; `plan_batches`
and `sample_batches` cut a `SceneSet` into batches and draw them in a seeded order. `evaluate` scores
what comes out, `predict` writes it: the same windows, seed and model give the same numbers in both.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import torch

from fftool.artifacts.schema import GOALS_FILE, GOALS_INDEX_FILE
from fftool.artifacts.store import Artifact
from fftool.config import EvaluateConfig, FairCode
from fftool.errors import FftoolError
from fftool.learning.batches import SceneBatch, SceneSet
from fftool.learning.cvae_model import Trained, most_likely, sample
from fftool.learning.features import prepare
from fftool.learning.protocols import constant_velocity, protocol_goals, repeat_windows, with_past_forces
from fftool.learning.training import generator
from fftool.models.dlow import QNet
from fftool.science.metrics import ade_fde
from fftool.variants import SPECS, reads_goal

# (batch, positions of its slots in the scene set's rows, -1 for padding) -> (B, K, A, 2) world goals
GoalsOf = Callable[[SceneBatch, np.ndarray], torch.Tensor]


class Predictor:
    """K world-frame futures (B, K, A, T, 2) and the goals they used (B, K, A, 2) for a padded batch."""

    def __init__(
        self,
        cfg: EvaluateConfig,
        trained: Trained | None,
        sampled_goals: np.ndarray | None,
        obs_len: int,
        pred_len: int,
        device: torch.device,
        sampler: QNet | None = None,
    ) -> None:
        """sampler: a DLow sampler of `trained` (its K codes replace the prior's draws), or None."""
        self.cfg, self.obs_len, self.pred_len, self.device = cfg, obs_len, pred_len, device
        self.sampler = sampler
        self.sampled_goals = sampled_goals
        self.gen = generator(cfg.seed, device)
        self.model = None
        self.variant = "cv"
        if trained is not None:
            self.model, self.model_cfg, self.forces_cfg, self.dt_s = trained
            self.variant = self.model_cfg.variant

    @property
    def protocol(self) -> str:
        """The goal protocol actually used: none for predictors that read no goal."""
        return self.cfg.protocol if reads_goal(self.variant) else "none"

    def goals(self, batch: SceneBatch, positions: np.ndarray) -> torch.Tensor:
        """(B, K, A, 2) world goals per sample under the protocol; the last observed position when unused."""
        k = self.cfg.k
        if self.protocol == "none":
            return batch.xy[:, None, :, self.obs_len - 1].expand(-1, k, -1, -1)
        sampled = None
        if self.sampled_goals is not None:
            safe = np.where(positions >= 0, positions, 0)
            sampled = torch.as_tensor(self.sampled_goals[safe], dtype=torch.float32, device=self.device)
        return protocol_goals(self.protocol, sampled, batch.xy[:, :, -1], k)

    def __call__(self, batch: SceneBatch, goals: torch.Tensor, noise: torch.Tensor | None = None) -> torch.Tensor:
        return self.draw(batch, goals, noise=noise)[0]

    def draw(
        self,
        batch: SceneBatch,
        goals: torch.Tensor,
        with_most_likely: bool = False,
        noise: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The K futures (B, K, A, T, 2) toward goals (B, K, A, 2) and, with_most_likely, the most-likely future
        (B, A, T, 2) toward goal 1 (`most_likely`) from the same rollout: one more code per window, or under the
        fair protocol one more window (goal 1, the prior's mean code), instead of a second rollout. The K
        futures are those drawn without it. noise: for a model drawing from its prior, the standard normal draws
        of its codes (B · K, A, Z), window-major, instead of the generator's (`cvae_model.sample`)."""
        k, obs_len = self.cfg.k, self.obs_len
        if self.model is None:
            if with_most_likely:
                raise ValueError("constant velocity has no prior: its sample 0 is its exact extrapolation")
            cfg = self.cfg
            past = batch.xy[:, :, :obs_len]
            return constant_velocity(past, self.pred_len, k, cfg.cv_angle_std_deg, cfg.cv_speed_std, self.gen), None
        B, _, A, _ = goals.shape
        mean_codes = self.cfg.mean_codes(self.variant)  # sample 1 is then the most-likely future itself
        extra = int(with_most_likely and not mean_codes)
        pick = None
        if self.protocol == "fair":  # a different goal per sample: every sample has its own past inputs
            if extra:  # one more window: goal 1, decoded from the prior's mean code
                goals = torch.cat([goals, goals[:, :1]], 1)
            windows = k + extra
            batch, goal, draws = repeat_windows(batch, windows), goals.reshape(B * windows, A, 2), 1
            if self.sampler is not None:  # sample j of a window decodes the sampler's code j
                pick = torch.arange(windows, device=self.device).repeat(B)
            elif extra:  # a prior draw per window
                pick = torch.zeros(B * windows, dtype=torch.long, device=self.device)
            if pick is not None and extra:
                pick[k::windows] = -1  # the extra window decodes the prior's mean code
                if noise is not None:  # ... with no draw
                    noise = torch.cat([noise.view(B, k, *noise.shape[1:]), noise.new_zeros(B, 1, *noise.shape[1:])], 1)
                    noise = noise.flatten(0, 1)
        else:
            goal, draws = goals[:, 0], k
        if self.forces_cfg is not None and self.dt_s is not None:  # dr, re: forces toward the goal used
            reads = SPECS[self.variant].training_reads
            batch = with_past_forces(batch, goal, self.forces_cfg, self.dt_s, obs_len, reads)
        prepared = prepare(batch, self.variant, obs_len, goal=goal)
        if mean_codes:  # each goal decoded from the prior's mean code
            futures = most_likely(self.model, prepared, self.model_cfg, self.forces_cfg, self.dt_s)
        else:
            futures = sample(
                self.model, prepared, self.model_cfg, self.forces_cfg, self.dt_s, draws, self.gen, self.sampler, pick,
                with_mean=bool(extra) and self.protocol != "fair", noise=noise,
            )  # fmt: skip
        futures = prepared.to_world(futures).reshape(B, k + extra, A, self.pred_len, 2)
        if not with_most_likely:
            return futures, None
        return futures[:, :k], futures[:, k if extra else 0]

    @torch.inference_mode()
    def most_likely(self, batch: SceneBatch, goal: torch.Tensor) -> torch.Tensor:
        """One world-frame future per agent (B, A, T, 2) toward `goal` (B, A, 2; ignored by goal-free variants):
        the CVAE's decoding of its prior's mean code (`cvae_model.most_likely`)."""
        if self.model is None:
            raise ValueError("constant velocity has no prior: its sample 0 is its exact extrapolation")
        if self.forces_cfg is not None and self.dt_s is not None:
            reads = SPECS[self.variant].training_reads
            batch = with_past_forces(batch, goal, self.forces_cfg, self.dt_s, self.obs_len, reads)
        prepared = prepare(batch, self.variant, self.obs_len, goal=goal)
        future = most_likely(self.model, prepared, self.model_cfg, self.forces_cfg, self.dt_s)
        return prepared.to_world(future)[:, 0]


def plan_batches(scenes: SceneSet, cfg: EvaluateConfig) -> list[np.ndarray]:
    """Every window of the scene set cut into padded batches, in an order drawn from `cfg.seed`."""
    rng = np.random.default_rng(cfg.seed)
    return scenes.plan(np.arange(scenes.windows), cfg.batch_windows, cfg.max_agent_pairs, rng)


# (batch, goals (B, K, A, 2), futures (B, K, A, T, 2)) -> (B, A, ...) arrays or tensors to keep per real agent
Fields = Callable[[SceneBatch, torch.Tensor, torch.Tensor], dict[str, "torch.Tensor | np.ndarray"]]


def collect(batches: Iterable[tuple[SceneBatch, torch.Tensor, torch.Tensor]], fields: Fields) -> dict[str, np.ndarray]:
    """What `fields` keeps of each sampled batch, for the real agents only, in the scene set's row order
    (its `row` column): how `evaluate` and `predict` turn padded batches back into agent-windows."""
    parts: dict[str, list[np.ndarray]] = {}
    for batch, goals, futures in batches:
        mask = batch.agent_mask.cpu().numpy()
        for name, values in ({"row": batch.row} | fields(batch, goals, futures)).items():
            array = values.cpu().numpy() if isinstance(values, torch.Tensor) else values
            parts.setdefault(name, []).append(array[mask])
    columns = {name: np.concatenate(values) for name, values in parts.items()}
    order = np.argsort(columns["row"])
    return {name: values[order] for name, values in columns.items()}


@torch.inference_mode()
def sample_batches(
    predictor: Predictor,
    scenes: SceneSet,
    plan: list[np.ndarray],
    goals_of: GoalsOf,
    device: torch.device,
    with_most_likely: bool = False,
) -> Iterator[tuple[SceneBatch, torch.Tensor, torch.Tensor]]:
    """(batch, goals (B, K, A, 2), futures (B, K, A, T, 2)) for each planned batch, in plan order;
    with_most_likely, the futures hold the most-likely future (`Predictor.draw`) after the K, (B, K + 1, A, T, 2).

    The predictor's generator runs through the batches in this order, so the plan fixes every number.
    """
    for members in plan:
        batch = scenes.batch(members).to(device)
        rows = batch.row.cpu().numpy()
        positions = np.where(rows >= 0, np.searchsorted(scenes.data.row, rows), -1)
        goals = goals_of(batch, positions)
        futures, likely = predictor.draw(batch, goals, with_most_likely)
        yield batch, goals, futures if likely is None else torch.cat([futures, likely[:, None]], 1)


def load_sampled_goals(goals: Artifact, scenes: SceneSet, benchmark: str, part: str) -> np.ndarray:
    """(M, K, 2) sampled goals of a goals artifact aligned with the scene set's agent-windows (checked key by key)."""
    return aligned_goals(goals.file(GOALS_INDEX_FILE), goals.file(GOALS_FILE), scenes, benchmark, part)


def aligned_goals(index_file: Path, goals_file: Path, scenes: SceneSet, benchmark: str, part: str) -> np.ndarray:
    """(M, K, 2) goals of `goals_file` (as `fftool sample-goals` writes it, keyed by `index_file`) aligned with the
    scene set's agent-windows, checked key by key; memory-mapped."""
    index = pq.read_table(index_file).to_pandas()
    rows = np.flatnonzero((index["benchmark"] == benchmark).to_numpy() & (index["part"] == part).to_numpy())
    if len(rows) != len(scenes.data) or not (
        np.array_equal(index["window_id"].to_numpy()[rows], scenes.data.window_id)
        and np.array_equal(index["ped_id"].to_numpy()[rows], scenes.data.ped_id)
    ):
        raise FftoolError(
            f"{index_file}: the goals of {benchmark}/{part} do not match the windows artifact "
            f"({len(rows)} goal rows for {len(scenes.data)} agent-windows); rebuild with fftool sample-goals"
        )
    return np.load(goals_file, mmap_mode="r")[rows]


@torch.no_grad()
def fair_min_ade_fde(
    trained: Trained,
    scenes: SceneSet,
    windows: np.ndarray,
    sampled_goals: np.ndarray,
    obs_len: int,
    k: int,
    seed: int,
    sampler: QNet | None = None,
    code: FairCode = "prior",
) -> tuple[float, float]:
    """minADE_K and minFDE_K (metres, per agent) of the windows `windows` of `scenes` under the fair protocol:
    sample k decodes sampled goal k (sampled_goals (M, K, 2), aligned with scenes.data), as `evaluate` does;
    with a DLow sampler, from its K codes; with code "mean", from the prior's mean code."""
    model, cfg = trained.model, trained.config
    device = next(model.parameters()).device
    evaluate = EvaluateConfig(protocol="fair", fair_code=code, k=k, seed=seed, batch_windows=cfg.batch_windows)
    pred_len = scenes.data.xy.shape[1] - obs_len
    predictor = Predictor(evaluate, trained, sampled_goals, obs_len, pred_len, device, sampler)
    plan = scenes.plan(windows, cfg.batch_windows, cfg.max_agent_pairs, np.random.default_rng(seed))
    ade, fde, count = 0.0, 0.0, 0
    for batch, _, futures in sample_batches(predictor, scenes, plan, predictor.goals, device):
        sample_ade, sample_fde = ade_fde(futures, batch.xy[:, :, obs_len:])  # (B, K, A)
        mask = batch.agent_mask
        ade += float((sample_ade.min(1).values * mask).sum())
        fde += float((sample_fde.min(1).values * mask).sum())
        count += int(mask.sum())
    return ade / max(count, 1), fde / max(count, 1)
