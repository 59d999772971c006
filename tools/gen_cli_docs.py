"""Write docs/cli.md from the live `--help` of every fftool command (run: python tools/gen_cli_docs.py).

tests/test_docs.py fails when docs/cli.md is out of date, so the reference never drifts from the code.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "cli.md"


def command_paths() -> list[tuple[str, ...]]:
    import typer.main

    from fftool.cli import app

    paths: list[tuple[str, ...]] = []

    def walk(command, prefix: tuple[str, ...]) -> None:
        for name, sub in getattr(command, "commands", {}).items():
            paths.append((*prefix, name))
            walk(sub, (*prefix, name))

    walk(typer.main.get_command(app), ())
    return paths


def render() -> str:
    os.environ.update({"COLUMNS": "100", "NO_COLOR": "1", "TERM": "dumb"})
    from typer.testing import CliRunner

    from fftool.cli import app

    runner = CliRunner()
    sections = [
        "# Command reference\n",
        "Generated from `--help` by `python tools/gen_cli_docs.py`; `tests/test_docs.py` checks it is current.\n",
    ]
    for path in [(), *command_paths()]:
        result = runner.invoke(app, [*path, "--help"], terminal_width=100, color=False)
        title = " ".join(("fftool", *path))
        body = "\n".join(line.rstrip() for line in result.output.strip().splitlines())
        sections.append(f"## `{title}`\n\n```text\n{body}\n```\n")
    return "\n".join(sections)


if __name__ == "__main__":
    text = render()
    if "--check" in sys.argv:
        sys.exit(0 if DOC.read_text() == text else "docs/cli.md is out of date: run python tools/gen_cli_docs.py")
    DOC.write_text(text)
    print(f"wrote {DOC}")
