"""An evaluation part with no valid agent-window is an error naming benchmark and part, never NaN metrics."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from fftool.artifacts.schema import FORCES_ARRAYS
from fftool.config import EvaluateConfig
from fftool.errors import FftoolError
from fftool.learning import batches
from fftool.learning.batches import AgentWindows
from fftool.stages import evaluate

OBS_LEN, PRED_LEN = 8, 12


def _empty_part(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> tuple[SimpleNamespace, SimpleNamespace]:
    """Stand-ins for the windows and forces artifacts of a part whose agent_windows rows are all absent."""
    window_len = OBS_LEN + PRED_LEN
    empty = AgentWindows(
        xy=np.zeros((0, window_len, 2)),
        source=np.zeros(0, dtype=object),
        first_step=np.zeros(0, np.int64),
        window_id=np.zeros(0, np.int64),
        ped_id=np.zeros(0, np.int64),
        row=np.zeros(0, np.int64),
    )
    monkeypatch.setattr(batches, "load_agent_windows", lambda *args, **kwargs: empty)
    shapes = {"goal": (0, 2), "speed0": (0, window_len), "group_id": (0,)}
    folder = tmp_path / "forces"
    folder.mkdir()
    for name, file in FORCES_ARRAYS.items():
        np.save(folder / file, np.zeros(shapes.get(name, (0, window_len, 2)), np.float32))
    windows = SimpleNamespace(manifest=SimpleNamespace(stats={"obs_len": OBS_LEN, "pred_len": PRED_LEN}))
    forces = SimpleNamespace(file=lambda name: folder / name)
    return windows, forces


def test_evaluating_a_part_without_agent_windows_is_an_error(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    windows, forces = _empty_part(monkeypatch, tmp_path)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    cfg = EvaluateConfig(predictor="cv", part="val")
    with pytest.raises(FftoolError) as info:
        evaluate.sample_and_score(cfg, "zara1", windows, forces, None, None, out_dir, torch.device("cpu"))
    message = str(info.value)
    assert "zara1/val" in message and "0 valid agent-windows" in message
    assert f"expected at least one pedestrian present for {OBS_LEN + PRED_LEN} consecutive steps" in message
    assert "\n" not in message
    assert list(out_dir.iterdir()) == []  # refused before anything is written


def test_summary_refuses_to_average_nothing() -> None:
    columns = {name: np.zeros(0) for name in ("min_ade", "min_fde", "collisions", "joint_collisions")}
    with pytest.raises(FftoolError, match=r"^eth/test has 0 valid agent-windows to evaluate: expected"):
        evaluate.summary(columns, EvaluateConfig(), "eth", "dr", "paper")
