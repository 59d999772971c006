"""The CLI: exit codes, exact error lines, the artifact root untouched on failure, help texts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from fftool import zoo
from fftool.cli import app

from .conftest import make_raw_tree, snapshot

runner = CliRunner()


def invoke(*args: str):
    return runner.invoke(app, [str(a) for a in args])


def test_ingest_builds_and_prints_the_summary(tmp_path: Path, raw_tree: Path) -> None:
    root = tmp_path / "artifacts"
    result = invoke("ingest", "--raw", raw_tree, "--root", root)
    assert result.exit_code == 0, result.output
    assert "valid agent-windows" in result.output and "zara2" in result.output
    again = invoke("ingest", "--raw", raw_tree, "--root", root)
    assert "stage 'tracks' is cached" in again.output and "stage 'windows' is cached" in again.output


def _corrupt(raw: Path, rel: str, line_no: int, replacement: str) -> Path:
    path = raw / rel
    lines = path.read_text().splitlines()
    lines[line_no - 1] = replacement
    path.write_text("\n".join(lines) + "\n")
    return path


BAD_INPUTS = {
    "non-numeric": (5, "10\t1\tfoo\t2.0", "x is not a number: 'foo'"),
    "columns": (7, "10\t1\t2.0", "expected 4 fields `frame_id ped_id x y`, found 3"),
    "nan": (3, "10\t1\tnan\t2.0", "x must be finite, found 'nan'"),
    "off stride": (4, "13\t1\t2.0\t2.0", "frame_id 13 is off the frame stride 10 (earlier frame ids are ≡ 0 mod 10)"),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
@pytest.mark.parametrize("with_previous_artifacts", [False, True])
def test_bad_raw_data_exits_1_and_leaves_the_root_as_it_was(
    tmp_path: Path, case: str, with_previous_artifacts: bool
) -> None:
    raw = make_raw_tree(tmp_path / "raw")
    root = tmp_path / "artifacts"
    if with_previous_artifacts:
        assert invoke("ingest", "--raw", raw, "--root", root).exit_code == 0
    before = snapshot(root)
    line_no, text, problem = BAD_INPUTS[case]
    path = _corrupt(raw, "val/students003_val.txt", line_no, text)
    result = invoke("ingest", "--raw", raw, "--root", root)
    assert result.exit_code == 1
    assert f"Error: {path}:{line_no}: {problem}" in result.output
    assert "Traceback" not in result.output
    assert snapshot(root) == before
    assert root.exists() == with_previous_artifacts


def test_missing_source_file_lists_what_is_missing(tmp_path: Path) -> None:
    raw = make_raw_tree(tmp_path / "raw")
    (raw / "train" / "uni_examples_train.txt").unlink()
    result = invoke("ingest", "--raw", raw, "--root", tmp_path / "a")
    assert result.exit_code == 1
    assert f"Error: {raw}: missing 1 of 24 expected Social-GAN files: train/uni_examples_train.txt" in result.output


def test_directory_without_sources(tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    result = invoke("ingest", "--raw", empty, "--root", tmp_path / "a")
    assert result.exit_code == 1
    assert "missing 24 of 24 expected Social-GAN files" in result.output
    assert not (tmp_path / "a").exists()


def test_usage_errors_exit_2(tmp_path: Path, raw_tree: Path) -> None:
    assert invoke("ingest", "--raw", tmp_path / "nope").exit_code == 2
    assert invoke("ingest", "--bogus").exit_code == 2
    result = invoke("ingest", "--raw", raw_tree, "--root", tmp_path / "a", "--set", "ingest.stride=3")
    assert result.exit_code == 2
    assert "Error: invalid configuration in defaults with overrides" in result.output
    assert "unknown key 'ingest.stride'" in result.output
    bad_type = invoke("ingest", "--raw", raw_tree, "--root", tmp_path / "a", "--set", "ingest.frame_stride=ten")
    assert bad_type.exit_code == 2 and "ingest.frame_stride" in bad_type.output


def test_artifacts_list_show_verify(tmp_path: Path, raw_tree: Path) -> None:
    root = tmp_path / "artifacts"
    invoke("ingest", "--raw", raw_tree, "--root", root)
    listing = invoke("artifacts", "list", "--root", root)
    assert listing.exit_code == 0 and "tracks/" in listing.output and "windows/" in listing.output
    shown = invoke("artifacts", "show", "windows", "--root", root)
    assert shown.exit_code == 0 and '"schema_version": 1' in shown.output
    assert invoke("artifacts", "verify", "--root", root).exit_code == 0
    tracks_file = next((root / "tracks").iterdir()) / "tracks.parquet"
    tracks_file.write_bytes(tracks_file.read_bytes() + b"!")
    verify = invoke("artifacts", "verify", "--root", root)
    assert verify.exit_code == 1
    assert "CHANGED" in verify.output and "tracks.parquet: content changed" in verify.output
    assert "Error: 1 of 2 artifact(s) changed, damaged or missing" in verify.output
    missing = invoke("artifacts", "show", "forces", "--root", root)
    assert missing.exit_code == 1 and "Error: no artifact matches 'forces'" in missing.output


def _commands(group=None, prefix=()):
    import typer.main

    command = typer.main.get_command(app) if group is None else group
    for name, sub in getattr(command, "commands", {}).items():
        yield (*prefix, name), sub
        yield from _commands(sub, (*prefix, name))


@pytest.mark.parametrize("path", [p for p, _ in _commands()], ids=" ".join)
def test_every_command_has_a_purpose_and_an_example(path: tuple[str, ...]) -> None:
    result = invoke(*path, "--help")
    assert result.exit_code == 0
    assert "Example" in result.output
    assert len(result.output.strip().splitlines()) > 3


def test_top_level_help_does_not_import_torch_or_pyarrow() -> None:
    code = (
        "import sys; from typer.testing import CliRunner; from fftool.cli import app;"
        "r = CliRunner().invoke(app, ['--help']); assert r.exit_code == 0, r.output;"
        "print(sorted(m for m in ('torch', 'pyarrow', 'pandas') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
    assert (
        "Example: fftool ingest"
        in subprocess.run([sys.executable, "-m", "fftool", "--help"], capture_output=True, text=True, check=True).stdout
    )


def test_version() -> None:
    from fftool import __version__

    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0 and result.output.startswith(f"fftool {__version__}; models: ")
    assert str(zoo.models_root()) in result.output  # where the shipped models come from


def test_a_profile_is_a_file_or_a_shipped_profiles_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`fftool reproduce cpu` runs the profile the shipped models came with, from any folder (an installed
    fftool has no pipelines/ beside the user); a name that is neither is one usage error listing the names."""
    from fftool.cli.app import profile_file

    monkeypatch.chdir(tmp_path)
    assert profile_file(Path("quick")) == zoo.pipelines_root() / "quick.toml"
    (tmp_path / "quick").write_text("")  # a file of that name is the user's, and wins
    assert profile_file(Path("quick")) == Path("quick")
    result = CliRunner().invoke(app, ["reproduce", "nosuch"])
    assert result.exit_code == 2 and "nosuch: no such file, nor a shipped profile's name (cpu, paper, quick)" in (
        result.output
    )
