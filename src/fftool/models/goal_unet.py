"""The goal estimator's U-Net (Goal-SAR layout): heat maps + semantic channels -> goal logits.

Encoder: DoubleConv blocks of the given widths with a 2×2 max-pool between them; decoder: bilinear ×2,
3×3 conv, concatenate the skip, DoubleConv, mirroring the encoder; head: 1×1 conv to one logit map per
supervised future step (the goal's last).
No BatchNorm (Goal-SAR). Inputs of any size are padded to a multiple of 2^depth and the output is
cropped back, so skips always align (Goal-SAR's centre-crop misalignment is avoided).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def _double_conv(c_in: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, padding=1),
        nn.ReLU(inplace=True),
        nn.Conv2d(c_out, c_out, 3, padding=1),
        nn.ReLU(inplace=True),
    )


class GoalUNet(nn.Module):
    """(B, C_in, H, W) -> (B, out_channels, H, W) logit maps of future positions, the goal's last."""

    def __init__(
        self,
        *,
        in_channels: int,
        widths: tuple[int, ...] = (32, 32, 64, 64, 64),
        prior_logit: float = 0.0,
        out_channels: int = 1,
    ) -> None:
        super().__init__()
        assert len(widths) >= 2, f"a U-Net needs at least two levels, got widths {widths}"
        self.depth = len(widths) - 1
        self.encoder = nn.ModuleList()
        previous = in_channels
        for width in widths:
            self.encoder.append(_double_conv(previous, width))
            previous = width
        self.up_convs, self.decoder = nn.ModuleList(), nn.ModuleList()
        for skip_width in reversed(widths[:-1]):
            self.up_convs.append(nn.Conv2d(previous, skip_width, 3, padding=1))
            self.decoder.append(_double_conv(2 * skip_width, skip_width))
            previous = skip_width
        self.head = nn.Conv2d(previous, out_channels, 1)
        # Start every cell at the target's prior probability instead of 0.5, so the first steps are spent
        # on finding the goal rather than on pushing thousands of background cells down.
        nn.init.constant_(self.head.bias, prior_logit)

    def forward(self, x: Tensor) -> Tensor:
        B, C, H, W = x.shape  # (B, C, H, W) batch, channels, rows, cols
        multiple = 2**self.depth
        x = F.pad(x, (0, -W % multiple, 0, -H % multiple))
        skips = []
        for level, block in enumerate(self.encoder):
            x = block(x if level == 0 else F.max_pool2d(x, 2))
            skips.append(x)
        skips.pop()  # the bottleneck is not a skip
        for up_conv, block in zip(self.up_convs, self.decoder):
            x = up_conv(F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False))
            x = block(torch.cat([x, skips.pop()], dim=1))
        return self.head(x)[:, :, :H, :W]  # (B, out_channels, H, W)
