"""Outputs written in place of others: temporaries that no planted link redirects, report folders that keep
what a user added, animation names that stay inside --out."""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import pandas as pd
import pytest
from typer.testing import CliRunner

from fftool import outputs
from fftool.cli import app
from fftool.errors import UsageError
from fftool.reporting import ablation
from fftool.reporting.plots import save_figure
from fftool.reporting.predictions import write_predictions


def _plant_links(out: Path, victim: Path) -> None:
    """Links at the names fftool once wrote its temporaries under (`.<name>.partial-<pid>`, `<name>.partial-<pid>`,
    `.<name>.partial`), for this process and its neighbours: a writer that follows one overwrites the victim."""
    for pid in range(os.getpid() - 2, os.getpid() + 3):
        for name in (f".{out.name}.partial-{pid}", f"{out.name}.partial-{pid}"):
            (out.parent / name).symlink_to(victim)
    (out.parent / f".{out.name}.partial").symlink_to(victim)


@pytest.mark.parametrize("kind", ["parquet", "png"])
def test_a_link_planted_where_a_temporary_might_go_is_never_followed(tmp_path: Path, kind: str) -> None:
    victim = tmp_path / "elsewhere" / "precious.txt"
    victim.parent.mkdir()
    victim.write_text("the user's data\n")
    out = tmp_path / "out" / f"result.{kind}"
    out.parent.mkdir()
    _plant_links(out, victim)
    if kind == "parquet":
        write_predictions(pd.DataFrame({"agent": [1], "x": [0.0]}), out, {"model": "test"})
    else:
        save_figure(plt.figure(), out)
    assert victim.read_text() == "the user's data\n"
    assert out.is_file() and not out.is_symlink() and out.stat().st_size > 0
    left = {p.name for p in out.parent.iterdir()} - {out.name}
    assert all((out.parent / name).is_symlink() for name in left)  # only the planted links; no temporary


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    out = tmp_path / "table.parquet"
    out.write_text("old")
    with pytest.raises(RuntimeError), outputs.replacing_file(out) as partial:
        partial.write_text("half")
        raise RuntimeError("killed half-way")
    assert out.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["table.parquet"]


def test_outputs_get_the_permissions_of_a_plain_file(tmp_path: Path) -> None:
    with outputs.replacing_file(tmp_path / "a.csv") as partial:
        partial.write_text("x")
    plain = tmp_path / "plain.csv"
    plain.write_text("x")
    assert (tmp_path / "a.csv").stat().st_mode == plain.stat().st_mode


def _report(folder: Path, files: dict[str, str]) -> None:
    """A report folder as write_report leaves it: its files and a marker listing them."""
    for name, text in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text(text)
    marker = ["written by fftool; the next report replaces this folder and these files:", *sorted(files)]
    (folder / ablation.REPORT_MARKER).write_text("\n".join(marker) + "\n")


def test_a_report_folder_keeps_what_the_user_added(tmp_path: Path) -> None:
    out = tmp_path / "reports" / "quick"
    out.mkdir(parents=True)
    _report(out, {"report.md": "# old", "results.csv": "a\n", "figures/scores.png": "png"})
    assert ablation.check_report_folder(out, tmp_path / "artifacts", tmp_path / "reports") == out.resolve()
    (out / "notes.md").write_text("my notes")
    (out / "my_plots").mkdir()
    (out / "my_plots" / "a.png").write_text("mine")
    with pytest.raises(UsageError, match=r"did not write \(my_plots/a.png, notes.md\)"):
        ablation.check_report_folder(out, tmp_path / "artifacts", tmp_path / "reports")
    assert (out / "notes.md").read_text() == "my notes"


def test_a_replaced_folder_goes_only_after_the_new_one_is_complete(tmp_path: Path) -> None:
    out = tmp_path / "report"
    out.mkdir()
    (out / "old.md").write_text("old")
    with pytest.raises(RuntimeError), outputs.replacing_folder(out) as partial:
        (partial / "new.md").write_text("new")
        raise RuntimeError("failed before the end")
    assert [p.name for p in out.iterdir()] == ["old.md"] and [p.name for p in tmp_path.iterdir()] == ["report"]
    with outputs.replacing_folder(out) as partial:
        (partial / "new.md").write_text("new")
    assert [p.name for p in out.iterdir()] == ["new.md"] and [p.name for p in tmp_path.iterdir()] == ["report"]


def test_an_animation_format_that_is_a_path_is_refused_before_any_work(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app,
        ["plot", "--benchmarks", "zara1", "--variants", "baseline", "--animate", "gif/../../../x.gif",
         "--out", str(tmp_path / "figures")],
    )  # fmt: skip
    assert result.exit_code == 2 and "expected one of gif, mp4" in result.output
    assert list(tmp_path.iterdir()) == []


def test_one_guard_refuses_what_fftool_did_not_write_for_every_kind(tmp_path: Path) -> None:
    """Files and folders alike: a link, the wrong type, a path under a file and a foreign output are refused
    before any work; fftool's own output, a new path and (for a folder) an empty one may be written."""
    ours = outputs.marked_file("a test file", lambda path: path.read_text() == "ours")
    folder = outputs.Kind("a test folder", True, lambda path: None if (path / "ours").exists() else "not ours")
    (tmp_path / "ours.txt").write_text("ours")
    (tmp_path / "mine.txt").write_text("mine")
    (tmp_path / "link.txt").symlink_to(tmp_path / "ours.txt")
    (tmp_path / "empty").mkdir()
    for out, kind in [(tmp_path / "ours.txt", ours), (tmp_path / "new.txt", ours), (tmp_path / "empty", folder)]:
        outputs.check_output(out, "--out", kind)
    refused = [
        (tmp_path / "mine.txt", ours, "exists and was not written by fftool"),
        (tmp_path / "link.txt", ours, "a symbolic link"),
        (tmp_path / "empty", ours, "a folder; give a file name"),
        (tmp_path / "mine.txt", folder, "a file; give a folder"),
        (tmp_path / "mine.txt" / "x.txt", ours, "mine.txt is a file, not a folder"),
    ]
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "notes.md").write_text("mine")
    refused.append((tmp_path / "full", folder, "not ours"))
    for out, kind, message in refused:
        with pytest.raises(UsageError, match=message):
            outputs.check_output(out, "--out", kind)
    assert (tmp_path / "mine.txt").read_text() == "mine" and (tmp_path / "full" / "notes.md").read_text() == "mine"
