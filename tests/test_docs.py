"""Docs stay true: the CLI reference is generated from --help, pipeline files load, README has two commands."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from fftool.config import load_config

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

import gen_cli_docs  # noqa: E402


def test_cli_reference_is_current() -> None:
    assert (ROOT / "docs" / "cli.md").read_text() == gen_cli_docs.render(), "run python tools/gen_cli_docs.py"


@pytest.mark.parametrize("path", sorted((ROOT / "pipelines").glob("**/*.toml")), ids=lambda p: p.name)
def test_pipeline_files_load(path: Path) -> None:
    load_config(path)


def test_readme_has_exactly_two_setup_commands() -> None:
    readme = (ROOT / "README.md").read_text()
    setup = readme.split("## Set-up", 1)[1].split("\n## ", 1)[0]
    commands = [line for block in re.findall(r"```bash\n(.*?)```", setup, re.S) for line in block.splitlines()]
    commands = [line for line in commands if line.strip() and not line.lstrip().startswith("#")]
    assert len(commands) == 2
    ci = (ROOT / ".ci" / "run").read_text()
    assert commands[1] in ci, ".ci/run must call the README's test command"
