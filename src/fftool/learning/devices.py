"""Which torch device to run on: the one answer for stages, `predict` and the API."""

from __future__ import annotations

import torch

from fftool.config import DEVICE_CHOICES
from fftool.errors import UsageError


def resolve(name: str | torch.device) -> torch.device:
    """auto (CUDA when torch sees one, else the CPU), cpu, cuda or cuda:N; anything else is a UsageError."""
    if isinstance(name, torch.device):
        name = str(name)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except (RuntimeError, TypeError):
        raise UsageError(f"device {name!r}: expected one of {', '.join(DEVICE_CHOICES)} (or cuda:N)") from None
    if device.type not in ("cpu", "cuda"):
        raise UsageError(f"device {name!r}: expected one of {', '.join(DEVICE_CHOICES)} (or cuda:N)")
    if device.type == "cuda" and not torch.cuda.is_available():
        raise UsageError(f"device {name!r} was asked for, but torch sees no CUDA device; use auto or cpu")
    return device
