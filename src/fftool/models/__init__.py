"""Neural network modules: plain torch, configured by keyword, no I/O."""

from fftool.models.forceformer import ForceFormer
from fftool.models.goal_unet import GoalUNet

__all__ = ["ForceFormer", "GoalUNet"]
