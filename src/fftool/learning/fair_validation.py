"""A trained goal variant's validation numbers under the fair protocol, whatever it was trained and chosen with.

A CVAE trained with true goals is chosen by its validation minADE with true goals (0.04–0.06 m minFDE for goal
and re: no prediction has them). This scores it, or the DLow sampler over it, the way users meet it: sample k
decodes the goal module's goal k, on the validation windows its training validated on. `fftool models
validate` records the result in each shipped model's manifest; `benchmarks/fair_validation.py` prints it for
any trained CVAE.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from fftool.artifacts.store import Artifact, ArtifactStore
from fftool.config import FairCode
from fftool.errors import FftoolError
from fftool.learning.batches import load_scene_set
from fftool.learning.cvae_model import load_model, scale_output
from fftool.learning.dlow_model import load_sampler
from fftool.learning.sampling import fair_min_ade_fde, load_sampled_goals
from fftool.learning.training import validation_subset
from fftool.variants import SPECS


def _upstream(store: ArtifactStore, cvae: Artifact, kind: str) -> Artifact | None:
    source = cvae.manifest.sources.get(kind)
    if source is None:
        return None
    found = store.lookup(kind, source)
    if found is None:
        raise FftoolError(
            f"{store.root} has no {kind} artifact {source[:12]}… that {cvae.id} trained on; build it first"
        )
    return found


def fair_validation(
    store: ArtifactStore,
    goals: Artifact,
    cvae: Artifact,
    dlow: Artifact | None,
    device: torch.device,
    code: FairCode = "prior",
    windows: int | None = None,
    residual_scale: float = 1.0,
) -> dict[str, Any]:
    """minADE / minFDE@K (metres) of `cvae` (through `dlow` when given) on its validation windows, sample k
    decoding goal k of the goals artifact `goals`; with the number of windows and the goal U-Net they came from.
    The windows are those the model's own training validated on (the CVAE's or the sampler's fixed subset).
    code "mean": each goal decoded from the prior's mean code (evaluate.fair_code), the sampler unused.
    windows: score this many validation windows instead (drawn with the CVAE's seed, so models of one benchmark
    and seed share them), where the model's own subset is too small to tell two recipes apart.
    residual_scale: the decoder's output head times this factor (`cvae_model.scale_output`; 1 = as trained)."""
    trained = scale_output(load_model(cvae, device), residual_scale)
    cfg, benchmark = trained.config, str(cvae.manifest.stats["benchmark"])
    windowing = _upstream(store, cvae, "windows")
    assert windowing is not None, "every CVAE trains on a windows artifact"
    val = load_scene_set(
        windowing, _upstream(store, cvae, "forces"), benchmark, "val", reads=SPECS[cfg.variant].training_reads
    )
    sampled = np.asarray(load_sampled_goals(goals, val, benchmark, "val"))
    sampler = load_sampler(dlow, device) if dlow is not None else None
    if windows is None and dlow is not None:  # the sampler's own subset
        most, seed = int(dlow.manifest.params["val_max_windows"]), int(dlow.manifest.params["seed"])
    else:  # the CVAE's own subset (`cvae_model.val_windows`), or `windows` drawn the same way
        most, seed = cfg.val_max_windows if windows is None else windows, cfg.seed
    subset = validation_subset(val.windows, most, seed)
    ade, fde = fair_min_ade_fde(
        trained, val, subset, sampled, int(windowing.manifest.stats["obs_len"]), cfg.k, seed, sampler, code
    )
    return {
        "min_ade_m": round(ade, 6),
        "min_fde_m": round(fde, 6),
        "k": cfg.k,
        "code": code if sampler is None else "dlow",
        "windows": len(subset),
        "goal_unet": goals.manifest.sources["goal"],
    }
