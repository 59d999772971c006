"""The paper's claims (ForceFormer §IV), one by one, against our numbers with their paired intervals.

Each claim is split into statements about paired differences (variant minus reference on the same windows
and seeds, `Score.__sub__`) or relative changes (variant / reference − 1). A difference is *lower* when its
whole interval lies below 0, *higher* when above, else it is not settled. A claim holds when every statement
it makes is settled its way, does not hold when one is settled the other way, and otherwise we cannot tell.
A claimed size (Dr −26 % minFDE) holds when the change is settled below 0 and its interval reaches the least
change that rounds to the printed size (−25.5 %); it does not hold when the whole interval falls short of it
(docs/metrics.md, "Claims").
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
import pandas as pd

from fftool.dataset.scenes import BENCHMARKS
from fftool.paper import PAPER_NAMES
from fftool.reporting.scores import MEANS, Score
from fftool.reporting.tables import Grid, Table

Outcome = Literal["holds", "does not hold", "cannot tell"]
Settled = Literal["yes", "no", "unsure"]
LABELS: Final = {"min_ade": "minADE", "min_fde": "minFDE", "nc": "NC"}


@dataclass(frozen=True)
class Verdict:
    ours: str  # our numbers, each with its interval
    outcome: Outcome


def _total(metric: str) -> str:
    return "average" if metric in MEANS else "sum"


def _difference(grid: Grid, scene: str, variant: str, reference: str, metric: str) -> Score | None:
    ours, theirs = (grid.get(scene, p, metric, _total(metric)) for p in (variant, reference))
    return None if ours is None or theirs is None else ours - theirs


def _relative(grid: Grid, variant: str, reference: str, metric: str) -> Score | None:
    """variant / reference − 1 over all five scenes, per seed and per window resample (paired)."""
    total = _total(metric)
    ours, theirs = (grid.get(total, p, metric, total) for p in (variant, reference))
    if ours is None or theirs is None:
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        return Score(ours.per_seed / theirs.per_seed - 1, ours.replicates / theirs.replicates - 1)


def _lower(score: Score | None, level: float) -> Settled:
    """Whether a difference is settled below 0 (yes), above 0 (no), or not settled."""
    if score is None:
        return "unsure"
    low, high = score.interval(level)
    return "yes" if high < 0 else "no" if low > 0 else "unsure"


def _outcome(settled: Iterable[Settled]) -> Outcome:
    found = list(settled)
    return "holds" if all(s == "yes" for s in found) else "does not hold" if "no" in found else "cannot tell"


def _shown(score: Score | None, level: float, percent: bool = False, digits: int = 3) -> str:
    if score is None:
        return "n/a"
    low, high = score.interval(level)
    if percent:
        return f"{score.estimate:+.1%} [{low:+.1%}, {high:+.1%}]"
    return f"{score.estimate:+.{digits}f} [{low:+.{digits}f}, {high:+.{digits}f}]"


def _short(predictor: str) -> str:
    return PAPER_NAMES[predictor].removeprefix("ForceFormer-")


def _digits(metric: str) -> int:
    return 3 if metric in MEANS else 0


def _all_lower(grid: Grid, pairs: Iterable[tuple[str, str, str, str]]) -> Verdict:
    """(scene, variant, reference, metric) differences that the claim says are all below 0."""
    settled, shown = [], []
    for scene, variant, reference, metric in pairs:
        diff = _difference(grid, scene, variant, reference, metric)
        settled.append(_lower(diff, grid.level))
        name = f"{_short(variant)}−{_short(reference)}"
        shown.append(f"{scene} {LABELS[metric]} {name} {_shown(diff, grid.level, digits=_digits(metric))}")
    lower = sum(s == "yes" for s in settled)
    higher = sum(s == "no" for s in settled)
    summary = f"{lower} of {len(settled)} lower, {higher} higher, {len(settled) - lower - higher} not settled"
    return Verdict(summary + ("; " + "; ".join(shown) if len(shown) <= 4 else ""), _outcome(settled))


def _size(grid: Grid, variant: str, metric: str, claimed: float) -> Verdict:
    """variant against AgentFormer over all five scenes: a change of `claimed` (the least that rounds to the
    printed size, e.g. −0.255 for −26 %) or more."""
    change = _relative(grid, variant, "baseline", metric)
    if change is None:
        return Verdict("n/a", "cannot tell")
    low, high = change.interval(grid.level)
    if not np.isfinite([low, high]).all():
        return Verdict(_shown(change, grid.level, percent=True), "cannot tell")
    outcome: Outcome = "does not hold" if low > claimed else "holds" if high < 0 else "cannot tell"
    return Verdict(_shown(change, grid.level, percent=True), outcome)


def _goal_does_not_collide_less(grid: Grid) -> tuple[Settled, str]:
    diff = _difference(grid, "sum", "goal", "baseline", "nc")
    settled = _lower(diff, grid.level)
    return ("no" if settled == "yes" else "yes"), f"Goal−AgentFormer NC {_shown(diff, grid.level, digits=0)}"


def _collide_less(grid: Grid) -> Verdict:
    diffs = {v: _difference(grid, "sum", v, "baseline", "nc") for v in ("dr", "re")}
    settled = [_lower(d, grid.level) for d in diffs.values()]
    goal, goal_shown = _goal_does_not_collide_less(grid)
    shown = [f"{_short(v)}−AgentFormer NC {_shown(d, grid.level, digits=0)}" for v, d in diffs.items()]
    return Verdict("; ".join([*shown, goal_shown]), _outcome([*settled, goal]))


VARIANTS: Final = ("goal", "dr", "re")
Claim = tuple[str, Callable[[Grid], Verdict]]
CLAIMS: Final[tuple[Claim, ...]] = (
    (
        "Dr and Re beat AgentFormer on every subset (minADE and minFDE)",
        lambda g: _all_lower(
            g, [(s, v, "baseline", m) for v in ("dr", "re") for s in BENCHMARKS for m in ("min_ade", "min_fde")]
        ),
    ),
    ("On average, Dr −26 % minFDE against AgentFormer", lambda g: _size(g, "dr", "min_fde", -0.255)),
    ("On average, Re −17 % minADE against AgentFormer", lambda g: _size(g, "re", "min_ade", -0.165)),
    (
        "Every goal-using variant has a lower average minFDE than AgentFormer",
        lambda g: _all_lower(g, [("average", v, "baseline", "min_fde") for v in VARIANTS]),
    ),
    ("Dr and Re collide evidently less than AgentFormer (NC, all scenes); Goal does not", _collide_less),
    (
        "Goal is the weakest variant (the highest average minFDE of Goal, Dr, Re)",
        lambda g: _all_lower(g, [("average", v, "goal", "min_fde") for v in ("dr", "re")]),
    ),
    (
        "Dr has the lowest minFDE on univ and zara2",
        lambda g: _all_lower(
            g, [(s, "dr", other, "min_fde") for s in ("univ", "zara2") for other in ("baseline", "goal", "re")]
        ),
    ),
    (
        "Re has the fewest collisions in total (NC, all scenes)",
        lambda g: _all_lower(g, [("sum", "re", other, "nc") for other in ("baseline", "goal", "dr")]),
    ),
    ("Re: −19.8 % collisions against AgentFormer (NC, all scenes)", lambda g: _size(g, "re", "nc", -0.1975)),
)


def claims_table(grid: Grid, protocol: str) -> Table | None:
    """The claims table of a grid with all five benchmarks and every variant; None otherwise (a claim about
    averages or subsets cannot be checked on part of them)."""
    if not grid.complete or not {"baseline", *VARIANTS} <= set(grid.predictors):
        return None
    rows = [{"claim": text, "ours": (v := check(grid)).ours, "outcome": v.outcome} for text, check in CLAIMS]
    frame = pd.DataFrame(rows)
    caption = (
        f"Goal protocol {protocol!r}. Differences: variant minus reference on the same windows and seeds, with "
        f"{grid.level:.0%} moving-block bootstrap intervals (minADE/minFDE in m averaged over the five scenes or "
        "per scene, NC summed); sizes: relative changes over all five scenes. holds: every statement settled "
        "its way; does not hold: one settled the other way; cannot tell: not settled (reporting/claims.py)."
    )
    return Table("claims", "The paper's claims (§IV) against our numbers", frame, caption, frame)
