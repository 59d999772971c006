"""What tells the predictors apart: one record per CVAE input variant, read wherever a variant matters.

Predictors: baseline = AgentFormer, goal / dr / re = ForceFormer-Goal / -Dr / -Re (goal, driving force,
goal + repulsive force), cv = the constant-velocity reference, which has no model. Per step the encoder
reads baseline = [position, velocity]; goal = + [goal, position - goal]; dr = + [F_dr];
re = + [goal, position - goal, F_re]. The decoder drops the velocity, as AgentFormer's does.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Literal, get_args

ForceFormerVariant = Literal["goal", "dr", "re"]
Variant = Literal["baseline", ForceFormerVariant]
FORCEFORMER_VARIANTS: Final[tuple[ForceFormerVariant, ...]] = get_args(ForceFormerVariant)
VARIANTS: Final[tuple[Variant, ...]] = get_args(Variant)
PREDICTORS: Final[tuple[str, ...]] = ("cv", *VARIANTS)  # what `evaluate` scores, in the row order of every table


@dataclass(frozen=True)
class VariantSpec:
    """One variant's inputs. The forces arrays are those of the `forces` artifact (stages/forces.py):
    training reads the stored forces as inputs; sampling recomputes the past forces toward the sampled goal,
    so it reads only the decoder's desired speed and (re) the groups."""

    reads_goal: bool  # steers toward a goal: needs true goals in training and sampled (or given) ones after
    feature_dim: int  # encoder features per step
    decoder_dim: int  # decoder features per step
    training_reads: tuple[str, ...] = ()  # forces arrays its training reads
    sampling_reads: tuple[str, ...] = ()  # forces arrays its sampling reads

    @property
    def uses_forces(self) -> bool:
        """Whether its inputs include a social force: only then does it need force constants and a time step."""
        return bool(self.training_reads)


SPECS: Final[dict[str, VariantSpec]] = {
    "baseline": VariantSpec(reads_goal=False, feature_dim=4, decoder_dim=2),
    "goal": VariantSpec(reads_goal=True, feature_dim=8, decoder_dim=6),
    "dr": VariantSpec(reads_goal=True, feature_dim=6, decoder_dim=4,
                      training_reads=("f_dr", "speed0"), sampling_reads=("speed0",)),
    "re": VariantSpec(reads_goal=True, feature_dim=10, decoder_dim=8,
                      training_reads=("f_re", "group_id", "speed0"), sampling_reads=("group_id", "speed0")),
}  # fmt: skip


def reads_goal(predictor: str) -> bool:
    """Whether a predictor steers toward a goal: the ForceFormer variants do; cv and the baseline do not."""
    return predictor in SPECS and SPECS[predictor].reads_goal
