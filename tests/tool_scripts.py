"""The scripts in tools/ are not a package: tests load them by path and run their `main` as a shell would."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

TOOLS = Path(__file__).parents[1] / "tools"


def load_tool(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, TOOLS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run_tool(name: str, args: list[str], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> str:
    """What `python tools/<name>.py ARGS` prints."""
    monkeypatch.setattr(sys, "argv", [name, *args])
    load_tool(name).main()
    return capsys.readouterr().out
