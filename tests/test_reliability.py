"""Fault injection for fftool's data-safety promises, as a case table.

The tiny full DAG (`fftool reproduce tiny.toml`) is built once per module; every case works on its own
copy of that tree (raw files, scenes, profile, artifact root) and runs one command against a fault:
an unsafe `--out`, a corrupted or tampered input, a damaged store, a full or read-only disk, an
interrupt, a bad value. Each failing case must end in exactly one `Error: ` line with the right exit
code (2 usage, 1 data/integrity), no traceback, the file or artifact named, and the whole tree, user
folders and artifact root, byte for byte as it was, with no new artifact. Each succeeding case may
change only its own folders.
"""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import pathlib
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

import fftool.artifacts.store
from fftool import pipeline
from fftool.artifacts.hashing import sha256_file
from fftool.artifacts.store import MANIFEST, ArtifactStore
from fftool.config import load_config

from .conftest import make_raw_tree, snapshot
from .test_cli import invoke
from .test_maps import make_scene
from .test_reproduce import TINY_PIPELINE

DEVICE = ("--device", "cpu")

# ---------------------------------------------------------------------------------------------- the world


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """raw/, scenes/, tiny.toml and artifacts/ after `fftool reproduce tiny.toml`: every stage built once."""
    base = tmp_path_factory.mktemp("built")
    make_raw_tree(base / "raw")
    make_scene(base / "scenes" / "zara1")
    (base / "tiny.toml").write_text(TINY_PIPELINE.format(raw=str(base / "raw"), scenes=str(base / "scenes")))
    result = invoke("reproduce", base / "tiny.toml", "--root", base / "artifacts", *DEVICE)
    assert result.exit_code == 0, result.output
    return base


@dataclass
class World:
    """One case's own copy of the built tree."""

    base: Path

    @property
    def root(self) -> Path:
        return self.base / "artifacts"

    @property
    def profile(self) -> Path:
        return self.base / "tiny.toml"

    @property
    def raw(self) -> Path:
        return self.base / "raw"

    def common(self) -> list[str]:
        return ["-c", str(self.profile), "--root", str(self.root)]

    def ids(self) -> list[str]:
        return sorted(a.id for a in ArtifactStore(self.root).list())

    def artifact(self, kind: str, **stats: Any) -> Path:
        """The folder of the one artifact of `kind` whose params or stats hold `stats`."""
        found = []
        for artifact in ArtifactStore(self.root).list(kind):
            values = artifact.manifest.params | artifact.manifest.stats
            if all(values.get(k) == v for k, v in stats.items()):
                found.append(artifact.path)
        assert len(found) == 1, (kind, stats, found)
        return found[0]

    def user_folder(self, name: str = "mine") -> Path:
        """A user's folder with their own files, which no command may touch."""
        folder = self.base / name
        folder.mkdir()
        (folder / "thesis.tex").write_text("months of work\n")
        (folder / "data").mkdir()
        (folder / "data" / "notes.txt").write_text("keep me\n")
        return folder


@pytest.fixture
def world(built: Path, tmp_path: Path) -> World:
    base = tmp_path / "w"
    shutil.copytree(built, base)
    profile = base / "tiny.toml"
    profile.write_text(profile.read_text().replace(str(built), str(base)))
    return World(base)


def folders(base: Path) -> set[str]:
    """Every folder under base (snapshot() sees files only): an empty leftover counts as a change."""
    return {p.relative_to(base).as_posix() for p in base.rglob("*") if p.is_dir() and ".locks" not in p.parts}


def changed(before: dict[str, bytes], after: dict[str, bytes]) -> set[str]:
    return {name for name in before.keys() | after.keys() if before.get(name) != after.get(name)}


def error_line(result: Any, code: int) -> str:
    """The one `Error: ` line of a failed command, after checking the exit code and that nothing escaped."""
    assert result.exit_code == code, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1, result.output
    return errors[0]


def rewrite_manifest(folder: Path, edit: Callable[[dict[str, Any]], None]) -> None:
    data = json.loads((folder / MANIFEST).read_text())
    edit(data)
    (folder / MANIFEST).write_text(json.dumps(data, indent=2, sort_keys=True))


def rehash(folder: Path, name: str) -> None:
    """Make the manifest agree with a tampered file, so only the file's reader can notice."""
    path = folder / name

    def edit(data: dict[str, Any]) -> None:
        data["files"][name] = {"sha256": sha256_file(path), "bytes": path.stat().st_size}

    rewrite_manifest(folder, edit)


def flip_middle_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


# ------------------------------------------------------------------------------------------ failing cases


@dataclass(frozen=True)
class Act:
    """What a case's arrange step hands the runner: the command, and values for the expected words."""

    args: list[str]
    names: dict[str, str] = field(default_factory=dict)
    spy: list[Path] | None = None  # paths the store read, when the case checks that it read nothing outside


@dataclass(frozen=True)
class Fail:
    id: str
    what: str
    arrange: Callable[[World, pytest.MonkeyPatch], Act]
    code: int
    words: tuple[str, ...]  # each must be in the error line; {root}, {base} and Act.names are filled in
    output: tuple[str, ...] = ()  # and these anywhere in the output (verify's listing)


def _ablate(w: World, out: Path | str) -> Act:
    return Act(["ablate", *w.common(), *DEVICE, "--out", str(out)])


def _out_user_folder(w: World, mp: pytest.MonkeyPatch) -> Act:
    return _ablate(w, w.user_folder())


def _out_report_with_user_notes(w: World, mp: pytest.MonkeyPatch) -> Act:
    """A previous report the user wrote notes into: once deleted with the report, now refused and kept."""
    shutil.copytree(w.root / "reports" / "tiny", w.base / "report")
    (w.base / "report" / "notes.md").write_text("what I saw\n")
    (w.base / "report" / "my_plots").mkdir()
    (w.base / "report" / "my_plots" / "a.png").write_bytes(b"mine")
    return _ablate(w, w.base / "report")


def _out_dot_in_user_folder(w: World, mp: pytest.MonkeyPatch) -> Act:
    mp.chdir(w.user_folder())
    return _ablate(w, ".")


def _out_root(w: World, mp: pytest.MonkeyPatch) -> Act:
    return _ablate(w, w.root)


def _out_parent_of_root(w: World, mp: pytest.MonkeyPatch) -> Act:
    return _ablate(w, w.base)


def _out_root_via_symlink(w: World, mp: pytest.MonkeyPatch) -> Act:
    (w.base / "shortcut").symlink_to(w.root, target_is_directory=True)
    return _ablate(w, w.base / "shortcut")


def _home(w: World, mp: pytest.MonkeyPatch) -> Path:
    home = w.user_folder("home")
    mp.setenv("HOME", str(home))
    assert Path.home() == home
    return home


def _out_home(w: World, mp: pytest.MonkeyPatch) -> Act:
    return _ablate(w, _home(w, mp))


def _out_tilde(w: World, mp: pytest.MonkeyPatch) -> Act:
    _home(w, mp)
    return _ablate(w, "~")


def _out_parent_of_home(w: World, mp: pytest.MonkeyPatch) -> Act:
    home = w.base / "users" / "me"
    home.mkdir(parents=True)
    mp.setenv("HOME", str(home))
    return _ablate(w, w.base / "users")


def _out_file(w: World, mp: pytest.MonkeyPatch) -> Act:
    (w.base / "results.txt").write_text("a user's file\n")
    return _ablate(w, w.base / "results.txt")


def _out_inside_root(w: World, mp: pytest.MonkeyPatch) -> Act:
    return _ablate(w, w.root / "cvae")


def _out_reports_folder(w: World, mp: pytest.MonkeyPatch) -> Act:
    return _ablate(w, w.root / "reports")  # holds every profile's report; it is not one itself


def _plot(w: World, out: Path, variants: str = "dr") -> list[str]:
    return ["plot", "--variants", variants, "--count", "1", *w.common(), *DEVICE, "--out", str(out)]


def _user_png(path: Path) -> None:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.new("RGB", (8, 8), (200, 30, 30)).save(path)


def _plot_over_user_png(w: World, mp: pytest.MonkeyPatch) -> Act:
    figures = w.user_folder("figures")
    _user_png(figures / "qualitative_zara1.png")
    return Act(_plot(w, figures), {"png": str(figures / "qualitative_zara1.png")})


def _plot_out_file(w: World, mp: pytest.MonkeyPatch) -> Act:
    _user_png(w.base / "figure.png")
    return Act(_plot(w, w.base / "figure.png"))


def _tracks_flipped_ingest(w: World, mp: pytest.MonkeyPatch) -> Act:
    tracks = w.artifact("tracks")
    flip_middle_byte(tracks / "tracks.parquet")
    return Act(["ingest", *w.common(), "--set", "windows.window_stride=2"], {"id": f"tracks/{tracks.name}"})


def _tracks_flipped_forces(w: World, mp: pytest.MonkeyPatch) -> Act:
    tracks = w.artifact("tracks")
    flip_middle_byte(tracks / "tracks.parquet")
    return Act(["forces", *w.common(), *DEVICE, "--set", "forces.sigma_m=0.31"], {"id": f"tracks/{tracks.name}"})


def _forces_scaled_train(w: World, mp: pytest.MonkeyPatch) -> Act:
    forces = w.artifact("forces")
    values = np.load(forces / "f_dr.npy")
    np.save(forces / "f_dr.npy", values * 1000)  # still a valid .npy file; only its hash tells
    args = ["train-cvae", *w.common(), *DEVICE, "--variant", "dr", "--set", "cvae.seed=11"]  # dr reads f_dr
    return Act(args, {"id": f"forces/{forces.name}"})


def _verify_manifest(w: World, text: str | None) -> Act:
    cvae = w.artifact("cvae", variant="dr")
    if text is None:
        (cvae / MANIFEST).unlink()
    else:
        (cvae / MANIFEST).write_text(text)
    return Act(["artifacts", "verify", "--root", str(w.root)], {"folder": str(cvae)})


def _verify_not_json(w: World, mp: pytest.MonkeyPatch) -> Act:
    return _verify_manifest(w, "{not json")


def _verify_newer_fftool(w: World, mp: pytest.MonkeyPatch) -> Act:
    data = json.loads((w.artifact("cvae", variant="dr") / MANIFEST).read_text())
    data |= {"fftool_version": "9.0.0", "signature": "ed25519:…"}
    return _verify_manifest(w, json.dumps(data))


def _verify_no_manifest(w: World, mp: pytest.MonkeyPatch) -> Act:
    return _verify_manifest(w, None)


def _verify_chain(w: World, mp: pytest.MonkeyPatch) -> Act:
    cvae, forces = w.artifact("cvae", variant="dr"), w.artifact("forces")
    np.save(forces / "f_re.npy", np.load(forces / "f_re.npy") * 1000)
    names = {"cvae": f"cvae/{cvae.name}", "forces": f"forces/{forces.name}"}
    return Act(["artifacts", "verify", f"cvae/{cvae.name[:8]}", "--root", str(w.root)], names)


def _spy_reads(w: World, mp: pytest.MonkeyPatch) -> list[Path]:
    """Record every folder the store reads a manifest from or hashes."""
    seen: list[Path] = []
    read, hash_files = ArtifactStore._read, fftool.artifacts.store._hash_files
    mp.setattr(ArtifactStore, "_read", lambda self, folder: (seen.append(Path(folder)), read(self, folder))[1])
    mp.setattr(fftool.artifacts.store, "_hash_files", lambda folder: (seen.append(Path(folder)), hash_files(folder))[1])
    return seen


def _artifacts_ref(command: str, ref: str) -> Callable[[World, pytest.MonkeyPatch], Act]:
    def arrange(w: World, mp: pytest.MonkeyPatch) -> Act:
        outside = w.base / "bait" / "0123456789abcdef"  # shaped like an artifact, outside the root
        outside.mkdir(parents=True)
        (outside / MANIFEST).write_text((w.artifact("tracks") / MANIFEST).read_text())
        return Act(["artifacts", command, ref, "--root", str(w.root)], {"ref": ref}, _spy_reads(w, mp))

    return arrange


def _predictions_footer_plot(w: World, mp: pytest.MonkeyPatch) -> Act:
    evaluation = w.artifact("evaluate", variant="dr")
    path = evaluation / "predictions.parquet"
    data = path.read_bytes()
    path.write_bytes(data[:-8] + b"\x00\x00\x00\x00PAR0")  # footer length and magic gone
    return Act(_plot(w, w.base / "figures"), {"id": f"evaluate/{evaluation.name}"})


def _raw_frame_1e20(w: World, mp: pytest.MonkeyPatch) -> Act:
    path = w.raw / "val" / "students003_val.txt"
    lines = path.read_text().splitlines()
    lines[2] = "1e20\t1\t2.0\t2.0"
    path.write_text("\n".join(lines) + "\n")
    return Act(["ingest", *w.common()], {"where": f"{path}:3"})


def _train_set(*overrides: str) -> Callable[[World, pytest.MonkeyPatch], Act]:
    def arrange(w: World, mp: pytest.MonkeyPatch) -> Act:
        return Act(["train-cvae", *w.common(), *DEVICE, *(a for o in overrides for a in ("--set", o))])

    return arrange


def _binary_config(w: World, mp: pytest.MonkeyPatch) -> Act:
    path = w.base / "model.toml"
    path.write_bytes(bytes(range(256)) * 4)
    return Act(["ingest", "-c", str(path), "--root", str(w.root)], {"path": str(path)})


def _zero_windows(w: World, mp: pytest.MonkeyPatch) -> Act:
    return Act(["ingest", *w.common(), "--set", "windows.obs_len=400"])


def _tampered_model(make: Callable[[Path], None]) -> Callable[[World, pytest.MonkeyPatch], Act]:
    def arrange(w: World, mp: pytest.MonkeyPatch) -> Act:
        cvae = w.artifact("cvae", variant="baseline")
        make(cvae / "model.pt")
        rehash(cvae, "model.pt")  # `artifacts verify` would say ok: only the loader can notice
        args = ["evaluate", "--variant", "baseline", *w.common(), *DEVICE, "--set", "evaluate.seed=5"]
        return Act(args, {"model": str(cvae / "model.pt")})

    return arrange


def _garbage_model(path: Path) -> None:
    path.write_bytes(b"PK\x03\x04 this is not a checkpoint " * 40)


def _misfit_model(path: Path) -> None:
    saved = torch.load(path, weights_only=True)
    name = next(iter(saved["state_dict"]))
    saved["state_dict"][name] = torch.zeros(3, 1)
    torch.save(saved, path)


def _windows_damaged_ingest(w: World, mp: pytest.MonkeyPatch) -> Act:
    windows = w.artifact("windows")
    (windows / MANIFEST).write_text("{not json")
    return Act(["ingest", *w.common()], {"folder": str(windows)})


def _new_windows(w: World) -> Act:
    return Act(["ingest", *w.common(), "--set", "windows.window_stride=2"])


def _disk_full_hashing(w: World, mp: pytest.MonkeyPatch) -> Act:
    hash_files = fftool.artifacts.store._hash_files

    def full(folder: Path) -> dict[str, Any]:
        if ".incomplete" in Path(folder).parts:  # the new artifact's files; re-hashing inputs still works
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(folder))
        return hash_files(folder)

    mp.setattr(fftool.artifacts.store, "_hash_files", full)
    return _new_windows(w)


def _disk_full_manifest(w: World, mp: pytest.MonkeyPatch) -> Act:
    write_text = pathlib.Path.write_text

    def full(self: Path, *args: Any, **kwargs: Any) -> int:
        if self.name == MANIFEST and ".incomplete" in self.parts:
            write_text(self, "{", *args[1:], **kwargs)  # a torn write
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
        return write_text(self, *args, **kwargs)

    mp.setattr(pathlib.Path, "write_text", full)
    return _new_windows(w)


def _stage_raises(exc: BaseException) -> Callable[[World, pytest.MonkeyPatch], Act]:
    """The windows stage writes its files, then `exc` is raised inside the build."""

    def arrange(w: World, mp: pytest.MonkeyPatch) -> Act:
        stage = pipeline.STAGES["windows"]

        def broken(*args: Any, **kwargs: Any) -> dict[str, Any]:
            stage.build(*args, **kwargs)
            raise exc

        mp.setitem(pipeline.STAGES, "windows", dataclasses.replace(stage, build=broken))
        return _new_windows(w)

    return arrange


def _read_only_root(w: World, mp: pytest.MonkeyPatch) -> Act:
    replace = os.replace

    def read_only(src: Any, dst: Any, *args: Any, **kwargs: Any) -> None:
        if Path(dst).resolve().is_relative_to(w.root.resolve()):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(dst))
        replace(src, dst, *args, **kwargs)

    mp.setattr(fftool.artifacts.store.os, "replace", read_only)
    return _new_windows(w)


FAILURES = [
    # deletion / overwrite: refused before any work, exit 2
    Fail("out-user-folder", "ablate --out a folder of the user's files", _out_user_folder, 2,
         ("--out {base}/mine", "holds files fftool did not write", ".fftool-report")),
    Fail("out-report-with-user-files", "ablate --out a previous report holding the user's notes",
         _out_report_with_user_notes, 2, ("--out {base}/report", "did not write (my_plots/a.png, notes.md)")),
    Fail("out-dot-cwd", "ablate --out . from inside a user's folder", _out_dot_in_user_folder, 2,
         ("--out .", "the current directory")),
    Fail("out-root", "ablate --out the artifact root", _out_root, 2, ("--out {root}", "the artifact root")),
    Fail("out-parent-of-root", "ablate --out the folder holding the root", _out_parent_of_root, 2,
         ("--out {base}:", "the artifact root or holds it")),
    Fail("out-root-symlink", "ablate --out a symlink to the root", _out_root_via_symlink, 2, ("the artifact root",)),
    Fail("out-home", "ablate --out $HOME", _out_home, 2, ("--out {base}/home", "your home")),
    Fail("out-tilde", "ablate --out ~ (expanded by fftool)", _out_tilde, 2, ("--out ~", "your home")),
    Fail("out-parent-of-home", "ablate --out a parent of $HOME", _out_parent_of_home, 2, ("your home",)),
    Fail("out-file", "ablate --out an existing file", _out_file, 2, ("results.txt", "file")),
    Fail("out-inside-root", "ablate --out root/cvae", _out_inside_root, 2,
         ("--out {root}/cvae", "inside the artifact root")),
    Fail("out-reports-folder", "ablate --out root/reports (all reports)", _out_reports_folder, 2,
         ("--out {root}/reports", "did not write")),
    Fail("plot-over-user-png", "plot --out a folder with the user's qualitative_zara1.png", _plot_over_user_png, 2,
         ("{png}", "not written by fftool")),
    Fail("plot-out-file", "plot --out an existing PNG file", _plot_out_file, 2, ("figure.png", "file")),
    # corrupted inputs: exit 1, nothing built from them
    Fail("tracks-flipped-byte-ingest", "one byte of tracks.parquet flipped, then a new windows build",
         _tracks_flipped_ingest, 1, ("artifact {id}", "tracks.parquet: content changed", "fftool ingest --force")),
    Fail("tracks-flipped-byte-forces", "one byte of tracks.parquet flipped, then a new forces build",
         _tracks_flipped_forces, 1, ("artifact {id}", "tracks.parquet: content changed")),
    Fail("forces-x1000-train", "f_dr.npy × 1000 (a valid .npy), then a new CVAE", _forces_scaled_train, 1,
         ("artifact {id}", "f_dr.npy: content changed", "fftool forces --force")),
    Fail("verify-manifest-not-json", "artifacts verify with a `{not json` manifest", _verify_not_json, 1,
         ("1 of", "damaged"), ("DAMAGED", "{folder}/manifest.json: not an fftool manifest")),
    Fail("verify-manifest-newer", "artifacts verify with a manifest key of a newer fftool", _verify_newer_fftool, 1,
         ("1 of", "damaged"), ("DAMAGED", "unknown keys ['signature'] (written by fftool 9.0.0")),
    Fail("verify-manifest-missing", "artifacts verify with manifest.json deleted", _verify_no_manifest, 1,
         ("1 of", "damaged"), ("DAMAGED", "{folder}: no readable manifest.json")),
    Fail("verify-chain-upstream", "artifacts verify cvae/<id> after its forces input changed", _verify_chain, 1,
         ("1 of 4",), ("ok  {cvae}", "CHANGED  {forces}", "f_re.npy: content changed")),
    Fail("show-dotdot", "artifacts show ../..", _artifacts_ref("show", "../.."), 1, ("'../..'", "not an artifact id")),
    Fail("verify-dotdot", "artifacts verify ../..", _artifacts_ref("verify", "../.."), 1,
         ("'../..'", "not an artifact id")),
    Fail("verify-kind-dotdot", "artifacts verify cvae/../..", _artifacts_ref("verify", "cvae/../.."), 1,
         ("not an artifact id",)),
    Fail("show-absolute", "artifacts show /etc", _artifacts_ref("show", "/etc"), 1, ("not an artifact id",)),
    Fail("plot-predictions-footer", "corrupt Parquet footer of a cached evaluation, then plot",
         _predictions_footer_plot, 1, ("artifact {id}", "predictions.parquet: content changed")),
    Fail("store-damaged-folder-ingest", "ingest meets a windows folder with an unreadable manifest",
         _windows_damaged_ingest, 1, ("{folder}/manifest.json", "not an fftool manifest")),
    # one-line errors for bad values
    Fail("raw-frame-1e20", "frame id 1e20 in a raw file", _raw_frame_1e20, 1,
         ("{where}:", "frame_id must be an integer within int64", "'1e20'")),
    Fail("cvae-heads-3", "--set cvae.n_heads=3 with d_model 16", _train_set("cvae.n_heads=3"), 2,
         ("cvae.n_heads", "divisor of d_model = 16")),
    Fail("cvae-lr-inf", "--set cvae.lr=inf", _train_set("cvae.lr=inf"), 2, ("cvae.lr", "finite")),
    Fail("cvae-lr-nan", "--set cvae.lr=nan", _train_set("cvae.lr=nan"), 2, ("cvae.lr", "finite")),
    Fail("config-binary", "-c a binary file", _binary_config, 2, ("{path}", "not a UTF-8 TOML file")),
    Fail("zero-windows", "--set windows.obs_len=400: no window fits", _zero_windows, 1, ()),
    Fail("model-garbage-rehashed", "model.pt overwritten, manifest hash updated, then a new evaluation",
         _tampered_model(_garbage_model), 1, ("{model}", "not a valid fftool checkpoint", "train-cvae --force")),
    Fail("model-misfit-rehashed", "model.pt a valid torch file of other shapes, hash updated, then evaluate",
         _tampered_model(_misfit_model), 1, ("{model}", "not a valid fftool checkpoint", "do not fit")),
    # environment faults
    Fail("disk-full-hashing", "ENOSPC while the new artifact's files are hashed", _disk_full_hashing, 1,
         ("stage 'windows'", ".incomplete/windows-", "No space left on device", "no partial artifact was kept")),
    Fail("disk-full-manifest", "ENOSPC (after a torn write) on the new manifest", _disk_full_manifest, 1,
         ("stage 'windows'", "manifest.json", "No space left on device")),
    Fail("interrupted-build", "KeyboardInterrupt inside the windows build, after it wrote its files",
         _stage_raises(KeyboardInterrupt()), 1, ("interrupted", "no partial artifact was kept")),
    Fail("bug-in-stage", "an unexpected RuntimeError inside a build", _stage_raises(RuntimeError("boom")), 1,
         ("unexpected RuntimeError: boom", "FFTOOL_DEBUG=1")),
    Fail("read-only-root", "os.replace in the store raises EROFS", _read_only_root, 1,
         ("stage 'windows'", "Read-only file system")),
]  # fmt: skip


@pytest.mark.parametrize("case", FAILURES, ids=[c.id for c in FAILURES])
def test_fault_is_one_error_line_and_changes_nothing(case: Fail, world: World, monkeypatch: pytest.MonkeyPatch) -> None:
    act = case.arrange(world, monkeypatch)
    files, dirs, ids = snapshot(world.base), folders(world.base), world.ids()
    result = invoke(*act.args)
    line = error_line(result, case.code)
    names = {"root": str(world.root), "base": str(world.base), **act.names}
    for word in case.words:
        assert word.format(**names) in line, (word.format(**names), line)
    for word in case.output:
        assert word.format(**names) in result.output, (word.format(**names), result.output)
    assert changed(files, snapshot(world.base)) == set()
    assert folders(world.base) == dirs
    assert world.ids() == ids
    if act.spy is not None:
        outside = [p for p in act.spy if not p.resolve().is_relative_to(world.root.resolve())]
        assert outside == [], outside


# --------------------------------------------------------------------------------------- succeeding cases


@dataclass(frozen=True)
class Ok:
    id: str
    what: str
    # Arranges, yields (the runner takes its snapshot), then runs the command and checks its outcome.
    run: Callable[[World, pytest.MonkeyPatch], Iterator[None]]
    may_change: tuple[str, ...]  # paths under the world (prefixes) the command may write


def _ok(result: Any) -> Any:
    assert result.exit_code == 0, result.output
    assert result.exception is None, repr(result.exception)
    assert "Traceback" not in result.output and "Error: " not in result.output, result.output
    return result


def _report_written(folder: Path) -> None:
    assert (folder / "report.md").is_file() and (folder / ".fftool-report").is_file()
    assert "Table IV" in (folder / "report.md").read_text()


def _ablate_into_empty_folder(w: World, mp: pytest.MonkeyPatch) -> Iterator[None]:
    (w.base / "report").mkdir()
    yield
    _ok(invoke(*_ablate(w, w.base / "report").args))
    _report_written(w.base / "report")


def _ablate_into_new_folder(w: World, mp: pytest.MonkeyPatch) -> Iterator[None]:
    yield
    _ok(invoke(*_ablate(w, w.base / "new" / "report").args))
    _report_written(w.base / "new" / "report")


def _ablate_over_previous_report(w: World, mp: pytest.MonkeyPatch) -> Iterator[None]:
    shutil.copytree(w.root / "reports" / "tiny", w.base / "report")
    yield
    _ok(invoke(*_ablate(w, w.base / "report").args))
    _report_written(w.base / "report")


def _ablate_default_report(w: World, mp: pytest.MonkeyPatch) -> Iterator[None]:
    yield
    _ok(invoke("ablate", *w.common(), *DEVICE))
    _report_written(w.root / "reports" / "tiny")


def _plot_twice(w: World, mp: pytest.MonkeyPatch) -> Iterator[None]:
    figures = w.base / "figures"
    yield
    _ok(invoke(*_plot(w, figures)))
    first = (figures / "qualitative_zara1.png").read_bytes()
    _ok(invoke(*_plot(w, figures, "baseline,dr")))  # over fftool's own figures
    assert (figures / "qualitative_zara1.png").read_bytes() != first
    assert sorted(p.name for p in figures.iterdir()) == ["density_zara1.png", "qualitative_zara1.png"]


def _plot_next_to_user_files(w: World, mp: pytest.MonkeyPatch) -> Iterator[None]:
    figures = w.user_folder("figures")
    _user_png(figures / "qualitative_eth.png")  # another benchmark's name: not written, not touched
    yield
    _ok(invoke(*_plot(w, figures)))
    assert (figures / "qualitative_zara1.png").is_file() and (figures / "density_zara1.png").is_file()


def _weird_raw_path(w: World, mp: pytest.MonkeyPatch) -> Iterator[None]:
    weird = w.base / "tmp" / "we\"ird\\dir'"
    shutil.copytree(w.raw, weird)
    seen: list[str] = []
    run = pipeline.run
    mp.setattr(pipeline, "run", lambda cfg, *a, **k: (seen.append(cfg.data.raw_dir), run(cfg, *a, **k))[1])
    fresh = w.base / "fresh"
    yield
    _ok(invoke("ingest", "--raw", str(weird), "--root", str(fresh)))
    assert seen == [str(weird)]
    [tracks] = ArtifactStore(fresh).list("tracks")
    assert tracks.id == f"tracks/{w.artifact('tracks').name}"  # the same files, read from the odd path


def _scratch_checkpoint(w: World, seed: int, content: bytes) -> str:
    """Write `content` as the resume checkpoint of the baseline CVAE with `cvae.seed`; its fingerprint."""
    cfg = load_config(w.profile, [f"cvae.seed={seed}"], {"cvae.variant": "baseline"})
    fp = pipeline.resolve(cfg, ["cvae"], "zara1")[-1].fingerprint
    scratch = w.root / ".scratch" / f"cvae-{fp[:16]}"
    scratch.mkdir(parents=True)
    (scratch / "last.pt").write_bytes(content)
    return fp


def _garbage_resume_checkpoint(w: World, mp: pytest.MonkeyPatch) -> Iterator[None]:
    fp = _scratch_checkpoint(w, 3, b"PK\x03\x04" + b"\x00" * 100)  # a torn zip, as a crash might leave
    before = w.ids()
    yield
    result = _ok(invoke("train-cvae", *w.common(), *DEVICE, "--set", "cvae.seed=3"))
    assert "warning:" in result.output and "damaged resume checkpoint" in result.output
    assert set(w.ids()) - set(before) == {f"cvae/{fp[:16]}"}
    _ok(invoke("artifacts", "verify", "--root", str(w.root)))


def _garbage_resume_checkpoint_kept(w: World, mp: pytest.MonkeyPatch) -> Iterator[None]:
    """The warning says the damaged checkpoint is kept (for inspection): it must still be there after."""
    _scratch_checkpoint(w, 4, b"garbage")
    yield
    result = _ok(invoke("train-cvae", *w.common(), *DEVICE, "--set", "cvae.seed=4"))
    [said] = [line for line in result.output.splitlines() if "damaged resume checkpoint" in line]
    kept = said.split("set aside as ")[1].split(" ")[0]
    [aside] = (w.root / ".damaged").glob(f"*{kept}")
    assert aside.read_bytes() == b"garbage", f"the warning says it kept {kept}: {said}"


def _forced_rebuild_sets_damaged_aside(w: World, mp: pytest.MonkeyPatch) -> Iterator[None]:
    windows = w.artifact("windows")
    fp = json.loads((windows / MANIFEST).read_text())["fingerprint"]
    (windows / MANIFEST).write_text("{not json")
    files = snapshot(windows)
    yield
    result = _ok(invoke("ingest", *w.common(), "--force"))
    assert "moved to" in result.output and "not deleted" in result.output
    [aside] = (w.root / ".damaged").iterdir()
    assert snapshot(aside) == files
    assert ArtifactStore(w.root).lookup("windows", fp) is not None


OKS = [
    Ok("out-empty-folder", "ablate --out an empty folder: the report is written there",
       _ablate_into_empty_folder, ("report", "artifacts/report/")),
    Ok("out-new-folder", "ablate --out a folder that does not exist yet", _ablate_into_new_folder,
       ("new", "artifacts/report/")),
    Ok("out-previous-report", "ablate --out a previous fftool report: replaced whole", _ablate_over_previous_report,
       ("report", "artifacts/report/")),
    Ok("out-default", "ablate without --out: <root>/reports/tiny replaced", _ablate_default_report,
       ("artifacts/reports/tiny/", "artifacts/report/")),
    Ok("plot-rerun", "plot twice into one folder: fftool's own figures are replaced", _plot_twice, ("figures/",)),
    Ok("plot-beside-user-files", "plot into a folder holding other user files", _plot_next_to_user_files,
       ("figures/qualitative_zara1.png", "figures/density_zara1.png")),
    Ok("raw-path-quotes-backslash", "ingest --raw tmp/we\"ird\\dir' into a fresh root", _weird_raw_path,
       ("fresh/",)),
    Ok("resume-garbage-checkpoint", "a torn last.pt in the CVAE's scratch: warning, trained from epoch 1",
       _garbage_resume_checkpoint, ("artifacts/cvae/", "artifacts/.scratch/", "artifacts/.damaged/")),
    Ok("resume-garbage-kept", "the damaged last.pt is still there afterwards, as the warning says",
       _garbage_resume_checkpoint_kept, ("artifacts/cvae/", "artifacts/.scratch/", "artifacts/.damaged/")),
    Ok("force-sets-damaged-aside", "ingest --force over a windows folder with a broken manifest",
       _forced_rebuild_sets_damaged_aside, ("artifacts/tracks/", "artifacts/windows/", "artifacts/.damaged/")),
]  # fmt: skip


@pytest.mark.parametrize("case", OKS, ids=[c.id for c in OKS])
def test_safe_command_changes_only_its_own_folders(case: Ok, world: World, monkeypatch: pytest.MonkeyPatch) -> None:
    steps = case.run(world, monkeypatch)
    next(steps)  # arranged
    before, ids = snapshot(world.base), set(world.ids())
    for _ in steps:  # the command and its own checks
        pass
    stray = sorted(name for name in changed(before, snapshot(world.base)) if not name.startswith(case.may_change))
    assert stray == []
    assert not (world.root / ".incomplete").exists()
    if not any(p.startswith("artifacts/") for p in case.may_change):
        assert set(world.ids()) == ids


# ------------------------------------------------------------------------------------------- concurrency


def test_two_identical_trainings_at_once_build_one_artifact(world: World) -> None:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "FFTOOL_DEBUG": ""}
    args = [sys.executable, "-m", "fftool", "train-cvae", *world.common(), *DEVICE, "--set", "cvae.seed=21"]
    before = world.ids()
    procs = [
        subprocess.Popen(args, cwd=world.base, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    outputs = [proc.communicate(timeout=240) for proc in procs]
    for proc, (_, err) in zip(procs, outputs):
        assert proc.returncode == 0, err
        assert "Traceback" not in err and "Error: " not in err
    new = sorted(set(world.ids()) - set(before))
    assert len(new) == 1 and new[0].startswith("cvae/"), new
    assert sum("stage 'cvae': building" in err for _, err in outputs) == 1, [err for _, err in outputs]
    assert not (world.root / ".incomplete").exists() and not (world.root / ".scratch").exists()
    verify = invoke("artifacts", "verify", "--root", world.root)
    assert verify.exit_code == 0 and "CHANGED" not in verify.output and "DAMAGED" not in verify.output
