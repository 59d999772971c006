"""Every knob on one page: one frozen pydantic model per stage, and a strict loader.

A pipeline file (`pipelines/*.toml`) overrides the defaults and `--set section.key=value` overrides the
file. Unknown keys, type mismatches, infinities, NaNs and values out of range (alone or with respect to
another key of their section) raise `ConfigError` naming the key, before any stage runs. Each stage's fingerprint
hashes only its own section (resolved, defaults included), so changing a default rebuilds that stage. A variant's
own recipe (`[per_variant.<variant>.cvae]`, `.dlow`) replaces keys of those sections for that variant alone; the
fingerprint hashes the values it trained with (`variant_section`).
"""

from __future__ import annotations

import copy
import math
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Final, Literal, get_args, get_origin

from pydantic import BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator, model_validator
from pydantic_core import PydanticCustomError

from fftool.dataset.scenes import BENCHMARKS, DT_S, FRAME_STRIDE, OBS_LEN, PRED_LEN, Part
from fftool.errors import ConfigError
from fftool.variants import FORCEFORMER_VARIANTS, PREDICTORS, ForceFormerVariant, Variant, reads_goal

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on 3.10 only
    import tomli as tomllib

DEFAULT_RAW_DIR = "../shared/data/eth_ucy/raw"
FETCHED_RAW_DIR = "data/eth_ucy/raw"  # where `fftool fetch-data` places the files by default
# --device: how to run, never part of a fingerprint (learning.devices.resolve turns one into a torch device).
DEVICE_CHOICES: Final = ("auto", "cpu", "cuda")
DEFAULT_SCENES_DIR = "../shared/data/eth_ucy/scenes"


class _Section(BaseModel):
    # No inf or nan anywhere: they would pass most range checks, train to NaN and break the manifest's JSON.
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_booleans_for_numbers(cls, value: Any, info: ValidationInfo) -> Any:
        """`epochs = true` is a typo, not 1: pydantic's lax mode would read a boolean as a number."""
        if isinstance(value, bool) and info.field_name is not None:
            annotation = cls.model_fields[info.field_name].annotation
            if bool not in _leaf_types(annotation):
                raise ValueError(f"expected {_type_name(annotation)}, not the boolean {str(value).lower()}")
        return value


def _leaf_types(annotation: Any) -> set[Any]:
    """The plain types a field's annotation admits (through unions, Annotated and Literal values' types)."""
    origin, args = get_origin(annotation), get_args(annotation)
    if origin is Literal:
        return {type(arg) for arg in args}
    if origin is None:
        return {annotation}
    return {leaf for arg in args for leaf in _leaf_types(arg)}


def _type_name(annotation: Any) -> str:
    names = sorted(getattr(t, "__name__", str(t)) for t in _leaf_types(annotation))
    return " or ".join(names)


def _expected(key: str, expected: str, got: Any) -> PydanticCustomError:
    """A cross-field check's failure, blamed on `key` of the section (`_describe` adds the section)."""
    return PydanticCustomError(
        "cross_field", "{key}: expected {expected}", {"key": key, "expected": expected, "got": got}
    )


class DataConfig(_Section):
    """Where raw inputs live. Paths are not fingerprinted: raw files enter by content hash."""

    # Default: ../shared/data/eth_ucy/raw beside a checkout, or, where that is not and `fftool fetch-data` has
    # filled ./data/eth_ucy/raw, that folder.
    raw_dir: str = Field(
        default_factory=lambda: (
            FETCHED_RAW_DIR
            if not Path(DEFAULT_RAW_DIR).is_dir() and Path(FETCHED_RAW_DIR).is_dir()
            else DEFAULT_RAW_DIR
        )
    )
    # Scene images and world->pixel homographies, one folder per benchmark scene (for plots and maps).
    scenes_dir: str = DEFAULT_SCENES_DIR
    # A dataset TOML (docs/data.md, "Your own dataset"): its files replace ETH/UCY and its name is the one
    # benchmark. Empty: ETH/UCY from raw_dir and scenes_dir. Its description and files enter by content hash.
    dataset: str = ""


class IngestConfig(_Section):
    """Parsing and validation of the raw Social-GAN text files (stage `tracks`)."""

    # Raw frame ids step by this many video frames; a row off this stride is an error.
    frame_stride: int = Field(FRAME_STRIDE, gt=0)
    # Seconds per step; recorded so later stages never assume it (0.4 s, see scenes.DT_S).
    dt_s: float = Field(DT_S, gt=0)
    # A (frame, ped) row repeated with identical x, y: "warn" drops the copy and records it in the
    # manifest, "error" refuses the file. Repeats with different positions are always errors.
    duplicates: Literal["warn", "error"] = "warn"


class WindowsConfig(_Section):
    """Slicing tracks into 8 + 12 step windows for each leave-one-out benchmark (stage `windows`)."""

    obs_len: int = Field(OBS_LEN, ge=2)  # the last observed velocity needs two steps
    pred_len: int = Field(PRED_LEN, gt=0)
    # Steps between consecutive window start frames; 1 is the benchmark protocol.
    window_stride: int = Field(1, gt=0)


class ForcesConfig(_Section):
    """Social forces (Helbing & Molnár 1995, ForceFormer §III-B): every constant, with its default.

    The same object parameterises the `forces` stage and the model's decoder, so training and test-time
    features follow one definition. docs/forces.md explains each choice.
    """

    # Driving force F_dr = (v0 e - v) / tau.
    tau_s: float = Field(0.5, gt=0)  # relaxation time (Helbing & Molnár; socialforce, pysocialforce)
    # Desired speed v0: the pedestrian's mean observed speed (default), its current speed at each step
    # (socialforce's choice), or one constant for everyone.
    desired_speed: Literal["mean_observed", "current", "constant"] = "mean_observed"
    desired_speed_mps: float = Field(1.3, ge=0)  # used only when desired_speed = "constant"
    # Below this distance to the goal the desired direction is undefined and both forces are zero.
    goal_min_distance_m: float = Field(1e-3, gt=0)
    # Repulsive potential V(b) = V0 exp(-b / sigma) on the elliptical b.
    v0_m2_s2: float = Field(2.1, ge=0)
    sigma_m: float = Field(0.3, gt=0)
    ellipse_step_s: float = Field(0.4, ge=0)  # Δt in b: how far ahead beta's next step is taken
    # Field of view: weight 1 inside the cone of opening 2ε, c outside.
    fov_deg: float = Field(200.0, gt=0, le=360)  # 2ε (paper)
    fov_out_of_view: float = Field(0.5, ge=0, le=1)  # c (paper)
    # "force": Helbing's w(e_α, -f_αβ); "position": socialforce 0.2's w(e_α, r_β - r_α).
    fov_reading: Literal["force", "position"] = "force"
    # Groups: DBSCAN per observed step on everyone present; pairs in one cluster at more than
    # group_min_steps observed steps are a group and do not repel each other at any step.
    dbscan_eps_m: float = Field(1.0, gt=0)
    dbscan_min_samples: int = Field(2, ge=1)
    group_min_steps: int = Field(4, ge=0)  # σ (paper): "more than" 4 of the 8 observed steps
    # Who repels: the other valid agents of the window (AgentFormer's scene, default) or everyone
    # present at that step, valid or not.
    neighbours: Literal["valid", "present"] = "valid"


class MapsConfig(_Section):
    """World-aligned semantic rasters of each scene (stage `maps`), built from the image alone."""

    resolution_m: float = Field(0.25, gt=0)  # metres per cell (Goal-SAR's UCY cell is 0.17 m)
    margin_m: float = Field(2.0, ge=0)  # around the image's ground footprint
    # Colour clusters (k-means in CIE Lab) -> one channel each, ordered by mean lightness.
    colour_clusters: int = Field(4, ge=1, le=16)
    seed: int = 0  # k-means initialisation


class GoalConfig(_Section):
    """The U-Net goal estimator and its training (stage `goal`, command `fftool train-goal`)."""

    # Input crop around the last observed position, in cells of `resolution_m`.
    resolution_m: float = Field(0.5, gt=0)
    crop_cells: int = Field(48, gt=0)  # 48 × 0.5 m = ±12 m: covers the largest 12-step displacement
    heatmap_sigma_cells: float = Field(1.0, gt=0)  # Gaussian of each observed input position
    target_sigma_cells: float = Field(1.0, gt=0)  # Gaussian of the BCE target at the true future position
    # Output maps: the goal (the last future step) and, with n > 1, n - 1 earlier steps evenly spaced before
    # it, each supervised by its own BCE term (Goal-SAR supervises all 12); goals are drawn from the last.
    supervised_steps: int = Field(1, gt=0)
    # U-Net: encoder widths (one pooling between consecutive entries), decoder mirrors them.
    widths: tuple[Annotated[int, Field(gt=0)], ...] = Field((32, 32, 64, 64, 64), min_length=2)
    # Loss = BCE + MSE(softargmax goal, true goal) in cells, with `loss_lambda` on one of them.
    loss_lambda: float = Field(1e6, gt=0)  # the paper's λ
    lambda_scales: Literal["bce", "mse"] = "bce"  # Goal-SAR puts 1e6 on the BCE (docs/goal.md)
    epochs: int = Field(20, gt=0)
    batch_size: int = Field(64, gt=0)
    lr: float = Field(1e-4, gt=0)  # Adam, as Goal-SAR
    grad_clip: float = Field(1.0, gt=0)
    # Departures for short budgets (docs/goal.md): AdamW's decoupled decay, and a linear warm-up over
    # `warmup_fraction` of the optimizer steps followed by a cosine decay to 0 at the last step.
    optimizer: Literal["adam", "adamw"] = "adam"
    weight_decay: float = Field(0.0, ge=0)
    schedule: Literal["constant", "cosine"] = "constant"
    warmup_fraction: float = Field(0.0, ge=0, lt=1)
    # An extra input heat map at the constant-velocity goal (not in Goal-SAR; docs/goal.md).
    cv_channel: bool = False
    # Two extra input heat maps: where the scene's other walkers are at the last observed step, and their
    # constant-velocity goals (not in Goal-SAR; docs/goal.md).
    neighbour_channels: bool = False
    # Turn every crop so the last observed velocity points along +col (not in Goal-SAR); training then
    # augments with the mirror only.
    align_heading: bool = False
    # Training windows: every `train_stride`-th start step (Goal-SAR uses 5), at most `max_train` per epoch.
    train_stride: int = Field(5, gt=0)
    max_train: int = Field(0, ge=0)  # 0 = all
    augment: bool = True  # random rotation in [0, 2π) and mirror, applied to map and positions alike
    # An input channel of where the training part's pedestrians walked in the same place (learning/scene_prior.py;
    # not in Goal-SAR).
    scene_prior: Literal["none", "occupancy"] = "none"
    # Share of training windows played backwards (the goal becomes the first observed position; Goal-SAR: 0.5).
    time_reversal: float = Field(0.0, ge=0, le=1)
    # Walking-speed augmentation (not in Goal-SAR): each training window's positions scaled about its last observed
    # one by s, log-uniform in [1 / speed_scale, speed_scale], so the module meets slower and faster walkers in the
    # same places (the map keeps its size). 1 = off.
    speed_scale: float = Field(1.0, ge=1)
    # Share of training windows whose crop reads no scene map (all map channels zero), so the module also
    # learns the map-less inputs `fftool predict` and the API give it (not in Goal-SAR; docs/goal.md).
    map_dropout: float = Field(0.0, ge=0, le=1)
    val_max: int = Field(1000, ge=0)  # validation agent-windows per epoch (0 = all)
    seed: int = 0

    @model_validator(mode="after")
    def _fits_the_unet(self) -> GoalConfig:
        """The checks goalnet.build_model would otherwise fail on after the inputs are loaded."""
        multiple = 2 ** (len(self.widths) - 1)
        if self.crop_cells % multiple:
            raise _expected("crop_cells", f"a multiple of {multiple} (2 ** (len(widths) - 1))", self.crop_cells)
        limit = self.crop_cells / math.sqrt(2 * math.pi)
        for key in ("heatmap_sigma_cells", "target_sigma_cells"):  # a Gaussian that would fill the crop
            if getattr(self, key) >= limit:
                raise _expected(key, f"< crop_cells / sqrt(2π) = {limit:.4g}", getattr(self, key))
        return self


class _ConstantVelocity(_Section):
    """The constant-velocity reference (protocols.constant_velocity): sample 0 extrapolates the last observed
    velocity, samples 1..K-1 turn its heading and scale its speed by these standard deviations.

    One definition for the two sections that draw it: `goals` (its goal-FDE reference) and `evaluate` (the cv
    predictor). Each keeps its own keys, since each is part of only its own stage's fingerprint.
    """

    cv_angle_std_deg: float = Field(15.0, ge=0)  # heading noise
    cv_speed_std: float = Field(0.2, ge=0)  # speed factor noise


class GoalsConfig(_ConstantVelocity):
    """Goal sampling from the trained U-Net (stage `goals`, command `fftool sample-goals`), with the
    constant-velocity goals beside them."""

    k: int = Field(20, gt=0)
    method: Literal["ttst", "multinomial"] = "ttst"  # mode + k-means centres (Goal-SAR), or plain draws
    temperature: float = Field(1.0, gt=0)  # P = sigmoid(logits / T)
    threshold: float = Field(0.05, ge=0, lt=1)  # cells below threshold · max P are dropped (Goal-SAR's ρ)
    samples: int = Field(2000, gt=0)  # draws per agent clustered by k-means (Goal-SAR: 10,000)
    kmeans_iterations: int = Field(20, gt=0)
    # Goal 1: the map's argmax cell (0, Goal-SAR), or the P-weighted mean of the (2r+1)² cells around it (r).
    mode_radius_cells: int = Field(0, ge=0)
    parts: tuple[Part, ...] = Field(("val", "test"), min_length=1)
    seed: int = 0


class GoalTrainingConfig(_Section):
    """Where the goal-reading CVAEs (goal, dr, re) get their goals in training, and how their best epoch is
    chosen (stage `cvae`, which reads this section only for those variants and only when it departs from the
    paper's choice, so the paper's models keep their fingerprints)."""

    def reads_module(self) -> bool:
        """Whether training reads the goal module's goals (to train with them, or to choose the best epoch)."""
        return self.source != "true" or self.fair_best_epoch

    # true: each window's true end point; best epoch by validation minADE with true goals (the paper's choice).
    # module: the true end point moved by one of the goal module's own errors, drawn from its errors on the
    # validation windows it never trained on (the nearest of its K goals, in the window's heading frame, from
    # windows of a similar speed), so the decoder meets goals as wrong as the best of the K it gets at test;
    # best epoch by validation minADE under the fair protocol (sample k decodes the module's goal k).
    # fair: the posterior's reconstruction reads the true goal, and sample k of the best-of-K term decodes goal k
    # of a goal set the module drew for a validation window of the same speed, moved onto the window's true end
    # point (the fair protocol in the loss); best epoch under the fair protocol. One process (not torchrun).
    source: Literal["true", "module", "fair"] = "true"
    # source "true": choose the best epoch under the fair protocol too (the other sources always do).
    fair_best_epoch: bool = False
    true_share: float = Field(0.0, ge=0, le=1)  # module: the share of training agents that keep the true goal
    speed_bins: int = Field(8, gt=0)  # module: errors come from validation windows of the same speed quantile


class CVAEConfig(_Section):
    """The AgentFormer CVAE backbone and its ForceFormer input variant (defaults: AgentFormer ETH/UCY)."""

    # baseline: position, velocity; goal: + goal and position - goal; dr: + driving force;
    # re: + goal features + repulsive force (ForceFormer §III-A).
    variant: Variant = "baseline"
    d_model: int = Field(256, gt=0)
    n_heads: int = Field(8, gt=0)
    d_ff: int = Field(512, gt=0)
    dropout: float = Field(0.1, ge=0, lt=1)
    n_layers: int = Field(2, gt=0)  # each of: past encoder, future encoder, future decoder
    z_dim: int = Field(32, gt=0)
    k: int = Field(20, gt=0)  # samples from the prior at test time and in the best-of-K loss
    kl_min: float = Field(2.0, ge=0)  # free bits on the per-agent KL (AgentFormer's min_clip)
    # The decoder head's meaning (models/forceformer.py OutputType): AgentFormer's "offset" (sn_out_type
    # 'norm') or fftool's "cv_residual" (over constant velocity), "goal_residual" (over the constant-acceleration
    # curve to the goal) or "relaxation_residual" (over the path of the driving force alone to the goal, with
    # relaxation time relaxation_steps time steps: 5 = 2 s at 2.5 Hz); the last two for goal, dr and re only.
    output: Literal["offset", "cv_residual", "goal_residual", "relaxation_residual"] = "offset"
    relaxation_steps: float = Field(5.0, gt=0)
    out_init_std: float = Field(0.01, ge=0)  # the output head's N(0, std²) init (AgentFormer: 0.01)
    # Training (AgentFormer: Adam 1e-4, ×0.5 every 10 epochs; ForceFormer trains 50 epochs).
    epochs: int = Field(50, gt=0)
    lr: float = Field(1e-4, gt=0)
    optimizer: Literal["adam", "adamw"] = "adam"
    weight_decay: float = Field(0.0, ge=0)  # AdamW's decoupled decay (ignored by adam)
    # step: lr × decay_gamma every decay_every epochs (AgentFormer). cosine: linear warm-up over the first
    # warmup_fraction of the optimizer steps, then a half cosine to 0 at the end of the last epoch. Both
    # are functions of the step count, never of wall-clock time.
    schedule: Literal["step", "cosine"] = "step"
    decay_every: int = Field(10, gt=0)
    decay_gamma: float = Field(0.5, gt=0, le=1)
    warmup_fraction: float = Field(0.0, ge=0, lt=1)
    grad_clip: float = Field(0.0, ge=0)  # max global gradient norm; 0 = no clipping (AgentFormer)
    batch_windows: int = Field(32, gt=0)  # windows per optimizer step at most (the official code: 1)
    max_agent_pairs: int = Field(4096, gt=0)  # and at most this many windows × agents² per step (memory)
    train_k: int = Field(20, gt=0)  # prior samples in the best-of-K loss during training
    # fftool's option: the first epochs train the posterior's reconstruction and the KL alone, without the
    # best-of-K term (a latent that learns to carry the future before the prior is pulled to spread; 0: off).
    best_of_k_warmup_epochs: int = Field(0, ge=0)
    max_agents: int = Field(0, ge=0)  # cap agents per training window (AgentFormer eth: 32); 0 = none
    train_stride: int = Field(1, gt=0)  # use every n-th window start of the train part
    max_train_windows: int = Field(0, ge=0)  # per epoch, 0 = all
    rotate: bool = True  # random scene rotation in training (AgentFormer's rand_rot_scene)
    val_max_windows: int = Field(200, ge=0)  # validation windows per epoch (0 = all)
    # Speed options (docs/cvae.md): bf16 runs matrix products under torch.autocast (meant for CUDA;
    # CPUs without bf16 units get slower); compile wraps the transformer layers in torch.compile.
    precision: Literal["fp32", "bf16"] = "fp32"
    compile: bool = False
    seed: int = 0

    @model_validator(mode="after")
    def _heads_divide_the_width(self) -> CVAEConfig:
        if self.d_model % self.n_heads:
            raise _expected("n_heads", f"a divisor of d_model = {self.d_model}", self.n_heads)
        aims_at_goal = self.output in ("goal_residual", "relaxation_residual")
        if aims_at_goal and self.variant == "baseline":  # it would aim at the true end point
            raise _expected("output", "'offset' or 'cv_residual' for the baseline, which reads no goal", self.output)
        return self


class DLowConfig(_Section):
    """AgentFormer's second stage, the DLow sampler over a frozen CVAE (stage `dlow`, `fftool train-dlow`;
    docs/cvae.md "DLow"). Defaults: AgentFormer's ETH/UCY DLow configs (cfg/eth_ucy/<ds>_agentformer.yml)."""

    # The predictors whose evaluations draw their K futures through a DLow sampler; the others sample the
    # CVAE's prior (AgentFormer's "before DLow"). Empty: no DLow anywhere (the default, fftool's CVAE path).
    variants: tuple[Variant, ...] = ()
    k: int = Field(20, gt=0)  # codes per agent (sample_k): evaluations draw exactly this many (evaluate.k)
    qnet_hidden: tuple[Annotated[int, Field(gt=0)], ...] = (512, 256)  # qnet_mlp, tanh
    share_eps: bool = True  # one ε for every agent and sample
    train_w_mean: bool = True  # z = b in training and at test (A enters only through the KL)
    recon_weight: float = Field(5.0, ge=0)
    kl_weight: float = Field(0.1, ge=0)
    kl_min: float = Field(10.0, ge=0)  # the KL's clamp (free bits), summed over the K codes
    # The diversity weight and scale and the LR schedule are AgentFormer's per benchmark
    # (learning/dlow_model.AGENTFORMER: eth 20/10, hotel 5/5, univ 10/10, zara1 5/5 with a linear schedule,
    # zara2 5/5; a dataset of one's own takes zara1's). step: lr × decay_gamma every decay_every epochs;
    # linear: 1 for lr_fix_epochs, then down to ~0 at the last epoch (AgentFormer's LambdaLR).
    decay_every: int = Field(5, gt=0)
    decay_gamma: float = Field(0.5, gt=0, le=1)
    lr_fix_epochs: int = Field(10, ge=0)
    epochs: int = Field(50, gt=0)
    lr: float = Field(1e-4, gt=0)  # Adam
    grad_clip: float = Field(0.0, ge=0)  # 0 = none (AgentFormer)
    batch_windows: int = Field(32, gt=0)  # windows per optimizer step at most (the official code: 1)
    max_agent_pairs: int = Field(4096, gt=0)
    train_stride: int = Field(1, gt=0)
    max_train_windows: int = Field(0, ge=0)  # per epoch, 0 = all
    val_max_windows: int = Field(200, ge=0)  # validation windows per epoch (0 = all); the best epoch is kept
    seed: int = 0


FairCode = Literal["prior", "mean"]  # the code a goal decodes with under the fair protocol (EvaluateConfig)


class EvaluateConfig(_ConstantVelocity):
    """Test-time sampling and metrics (ForceFormer §IV-C; definitions in docs/metrics.md)."""

    # cvae: the trained model of the `cvae` section's variant; cv: the constant-velocity reference.
    predictor: Literal["cvae", "cv"] = "cvae"
    # Where goal variants get their goal: fair (sample k decodes sampled goal k: no true future read, what
    # predict and the API do), paper (the paper's pick: the sampled goal nearest the true end point), oracle
    # (the true end point). The baseline and cv read no goal.
    protocol: Literal["paper", "fair", "oracle"] = "fair"
    # Under the fair protocol, the code sample k decodes its goal k with: a draw from the prior (or the DLow
    # sampler's code k), as AgentFormer samples; or the prior's mean, so that the K goals alone spread the K
    # futures (docs/experiments/fair-training.md). Other protocols share one goal over K draws.
    fair_code: FairCode = "prior"
    k: int = Field(20, gt=0)
    part: Literal["test", "val"] = "test"
    collision_threshold_m: float = Field(0.1, gt=0)  # γ (paper); pairs closer than this collide
    batch_windows: int = Field(32, gt=0)  # windows per forward pass (speed only: results do not change)
    max_agent_pairs: int = Field(2048, gt=0)  # windows × agents² per pass (smaller passes are faster on CPU)
    seed: int = 0

    def mean_codes(self, predictor: str) -> bool:
        """Whether `predictor` decodes each of its K goals from the prior's mean code (a goal variant under the
        fair protocol with fair_code "mean"), rather than from draws or a DLow sampler's codes."""
        return reads_goal(predictor) and self.protocol == "fair" and self.fair_code == "mean"


class ReportConfig(_Section):
    """What `ablate` and `reproduce` cover and how the tables count (not part of any fingerprint)."""

    # ETH/UCY's, or a dataset's name (data.dataset; then the default is that one benchmark).
    benchmarks: tuple[str, ...] = Field(BENCHMARKS, min_length=1)
    variants: tuple[ForceFormerVariant, ...] = FORCEFORMER_VARIANTS  # baseline always included
    collision_pairs: Literal["ordered", "unordered"] = "ordered"  # the paper's sum is over m != n
    collision_sample: Literal["best_ade", "joint"] = "best_ade"  # per-agent best-ADE (paper) or one per window
    constant_velocity: bool = True  # add the cv reference rows
    out_dir: str = "reports"  # relative to the artifact root unless absolute
    # Seeds as a grid dimension (`--seeds`): every cell is trained and evaluated once per seed, each seed set
    # in SEEDED_SECTIONS; empty = one run with each section's own seed.
    seeds: tuple[Annotated[int, Field(ge=0)], ...] = ()
    # Percentile intervals from a bootstrap over test windows (science/bootstrap.py), paired across predictors.
    bootstrap_resamples: int = Field(2000, ge=100)
    bootstrap_seed: int = 0
    # Windows per block of the moving-block bootstrap: "auto" = windows as far apart as one window is long
    # share no step ((obs_len + pred_len) / window_stride, 20 for ETH/UCY); 1 = each window on its own.
    bootstrap_block: Annotated[int, Field(ge=1)] | Literal["auto"] = "auto"

    def block_length(self, windows: WindowsConfig) -> int:
        """The bootstrap's block length in windows (docs/metrics.md, "Intervals")."""
        if self.bootstrap_block != "auto":
            return self.bootstrap_block
        return -(-(windows.obs_len + windows.pred_len) // windows.window_stride)

    confidence: float = Field(0.95, gt=0, lt=1)

    @model_validator(mode="after")
    def _distinct_seeds(self) -> ReportConfig:
        """A seed named twice would train and count the same cells twice (as `--seeds 0,0` is refused)."""
        if len(set(self.seeds)) != len(self.seeds):
            raise _expected("seeds", "distinct seeds", list(self.seeds))
        return self


# The keys every variant shares: which variant a section trains, which predictors draw through DLow, and the
# seeds (grid parameters, set in every seeded section at once by `seeded_config`).
_SHARED_BY_VARIANTS: Final = frozenset({"variant", "variants", "seed"})


class VariantRecipe(_Section):
    """The cvae, dlow and evaluate keys one variant trains and samples with instead of the profile's
    (`[per_variant.<variant>.cvae]`): a recipe chosen on validation for one variant leaves the others, and their
    fingerprints, alone."""

    cvae: dict[str, Any] = {}
    dlow: dict[str, Any] = {}
    evaluate: dict[str, Any] = {}


def _with_overrides(section: _Section, overrides: Mapping[str, Any]) -> _Section:
    return type(section).model_validate(section.model_dump() | dict(overrides)) if overrides else section


class PipelineConfig(_Section):
    """The whole pipeline's configuration, as resolved from defaults, a file and overrides."""

    data: DataConfig = DataConfig()
    ingest: IngestConfig = IngestConfig()
    windows: WindowsConfig = WindowsConfig()
    forces: ForcesConfig = ForcesConfig()
    maps: MapsConfig = MapsConfig()
    goal: GoalConfig = GoalConfig()
    goals: GoalsConfig = GoalsConfig()
    goal_training: GoalTrainingConfig = GoalTrainingConfig()
    cvae: CVAEConfig = CVAEConfig()
    dlow: DLowConfig = DLowConfig()
    evaluate: EvaluateConfig = EvaluateConfig()
    report: ReportConfig = ReportConfig()
    # A variant's own recipe: its keys replace the cvae and dlow sections' when that variant trains
    # (`variant_section`); a fingerprint records the values a model trained with, never this table.
    per_variant: dict[Variant, VariantRecipe] = {}

    @model_validator(mode="after")
    def _per_variant_recipes_resolve(self) -> PipelineConfig:
        """Every variant's recipe names keys of its section that the section accepts with those values."""
        for variant, recipe in self.per_variant.items():
            for name in VariantRecipe.model_fields:
                where, overrides = f"per_variant.{variant}.{name}", getattr(recipe, name)
                shared = sorted(overrides.keys() & _SHARED_BY_VARIANTS)
                if shared:
                    raise _expected(
                        f"{where}.{shared[0]}",
                        "a key the variants may differ in (not variant, variants or seed)",
                        shared[0],
                    )
                as_trained = {"variant": variant} if name == "cvae" else {}  # checked as that variant trains
                try:
                    _with_overrides(getattr(self, name), {**overrides, **as_trained})
                except ValidationError as exc:
                    issue = exc.errors()[0]
                    if issue["type"] == "cross_field":
                        raise _expected(
                            f"{where}.{issue['ctx']['key']}", issue["ctx"]["expected"], issue["ctx"]["got"]
                        ) from None
                    key = ".".join(str(part) for part in issue["loc"])
                    expected = f"a key of the [{name}] section" if issue["type"] == "extra_forbidden" else issue["msg"]
                    raise _expected(f"{where}.{key}", expected, issue.get("input")) from None
        return self


# The stage sections of a configuration (per_variant is recipes over three of them, not a section).
SECTIONS: Final = tuple(name for name in PipelineConfig.model_fields if name != "per_variant")


def variant_section(cfg: PipelineConfig, name: str) -> _Section:
    """Section `name` as the cvae section's variant runs with it: the profile's, with the keys that variant sets
    in `[per_variant.<variant>.<name>]` (cvae, dlow, evaluate). Fingerprints and builds read sections through this."""
    if name not in SECTIONS:
        raise AttributeError(f"{name!r} is not a configuration section")
    section = getattr(cfg, name)
    overrides = getattr(cfg.per_variant.get(cfg.cvae.variant), name, None)
    return _with_overrides(section, overrides) if overrides else section


# What a grid seed sets: every stage whose result depends on random numbers of training or sampling. The
# data stages (tracks, windows, forces) draw none and maps' k-means seed describes the scene, not a run, so
# a seed leaves them, and their fingerprints, alone.
SEEDED_SECTIONS: Final = ("goal", "goals", "cvae", "dlow", "evaluate")


def seeded_config(cfg: PipelineConfig, seed: int) -> PipelineConfig:
    """The configuration of one grid seed: `seed` in every section of SEEDED_SECTIONS. Seed 0 is the default
    of each, so a profile that sets no seed keeps its artifacts (and fingerprints) as grid seed 0."""
    sections = {name: getattr(cfg, name).model_copy(update={"seed": seed}) for name in SEEDED_SECTIONS}
    return cfg.model_copy(update=sections)


def benchmark_names(cfg: PipelineConfig) -> tuple[str, ...]:
    """The benchmarks the data offers: the five ETH/UCY scenes, or a dataset's one name (data.dataset)."""
    if not cfg.data.dataset:
        return BENCHMARKS
    from fftool.dataset.custom import load_dataset

    return (load_dataset(cfg.data.dataset).name,)


def _dataset_benchmarks(cfg: PipelineConfig, chosen: bool, origin: str) -> PipelineConfig:
    """With data.dataset, report.benchmarks defaults to the dataset's one name (the dataset is read here, so a
    bad dataset TOML fails before any stage runs). Benchmarks the data lacks fail when a stage is planned
    (`pipeline.resolve`), so `--benchmarks` on the command line can still choose among the data's."""
    from fftool.errors import RawDataError

    try:
        offered = benchmark_names(cfg)
    except RawDataError as exc:
        raise ConfigError(f"invalid configuration in {origin}: data.dataset: {exc}") from exc
    if cfg.data.dataset and not chosen:
        return cfg.model_copy(update={"report": cfg.report.model_copy(update={"benchmarks": offered})})
    return cfg


def predictor_config(cfg: PipelineConfig, predictor: str) -> PipelineConfig:
    """The configuration whose `evaluate` target scores `predictor`: a CVAE variant, or cv."""
    if predictor not in PREDICTORS:
        raise ValueError(f"unknown predictor {predictor!r}; one of {', '.join(PREDICTORS)}")
    if predictor == "cv":
        return cfg.model_copy(update={"evaluate": cfg.evaluate.model_copy(update={"predictor": "cv"})})
    return cfg.model_copy(
        update={
            "cvae": cfg.cvae.model_copy(update={"variant": predictor}),
            "evaluate": cfg.evaluate.model_copy(update={"predictor": "cvae"}),
        }
    )


def _parse_value(text: str) -> Any:
    """Read an override value as TOML (numbers, booleans, lists, quoted strings), else a bare string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def apply_overrides(
    raw: dict[str, Any], overrides: list[str], values: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """Apply `section.key=value` strings, then typed `{"section.key": value}` values, to a nested dict.

    Typed values (what CLI options already parsed, e.g. a path) are set as they are, never turned into
    text and parsed again. Unknown sections fail in validation.
    """
    merged = copy.deepcopy(raw)
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep:
            raise ConfigError(f"override {item!r}: expected section.key=value, e.g. ingest.frame_stride=10")
        _set(merged, key.strip(), _parse_value(value.strip()), f"override {item!r}")
    for key, value in (values or {}).items():
        _set(merged, key, value, f"value for {key!r}")
    return merged


def _set(merged: dict[str, Any], key: str, value: Any, what: str) -> None:
    """section.key, or per_variant.<variant>.<section>.key for one variant's recipe."""
    parts = key.split(".")
    depth = 4 if parts[0] == "per_variant" else 2
    if len(parts) != depth or not all(parts):
        raise ConfigError(
            f"{what}: expected section.key=value, e.g. ingest.frame_stride=10, or "
            "per_variant.<variant>.<section>.key=value, e.g. per_variant.baseline.cvae.epochs=20"
        )
    target = merged
    for level, part in enumerate(parts[:-1], start=1):
        target = target.setdefault(part, {})
        if not isinstance(target, dict):
            raise ConfigError(f"{what}: {'.'.join(parts[:level])!r} is not a section")
    target[parts[-1]] = value


def _describe(error: ValidationError, origin: str) -> str:
    lines = []
    for issue in error.errors():
        key = ".".join(str(part) for part in issue["loc"])
        if issue["type"] == "extra_forbidden":
            lines.append(f"unknown key {key!r}")
        elif issue["type"] == "cross_field":
            context = issue["ctx"]
            lines.append(
                f"{key + '.' if key else ''}{context['key']}: expected {context['expected']} (got {context['got']!r})"
            )
        else:
            lines.append(f"{key}: {issue['msg']} (got {issue.get('input')!r})")
    return f"invalid configuration in {origin}: " + "; ".join(lines)


def load_config(
    path: Path | None = None, overrides: list[str] | None = None, values: Mapping[str, Any] | None = None
) -> PipelineConfig:
    """Resolve defaults ← TOML file ← `--set` overrides ← typed values into a validated `PipelineConfig`."""
    raw: dict[str, Any] = {}
    origin = "defaults"
    if path is not None:
        origin = str(path)
        try:
            raw = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        except FileNotFoundError as exc:
            raise ConfigError(f"{path}: no such pipeline file") from exc
        except UnicodeDecodeError as exc:
            raise ConfigError(f"{path}: not a UTF-8 TOML file (undecodable byte at offset {exc.start})") from exc
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{path}: not valid TOML ({exc})") from exc
    if overrides or values:
        raw = apply_overrides(raw, list(overrides or []), values)
        origin = f"{origin} with overrides {[*(overrides or []), *(values or {})]}"
    try:
        cfg = PipelineConfig.model_validate(raw)
    except ValidationError as exc:
        raise ConfigError(_describe(exc, origin)) from exc
    report = raw.get("report")
    return _dataset_benchmarks(cfg, isinstance(report, dict) and "benchmarks" in report, origin)
