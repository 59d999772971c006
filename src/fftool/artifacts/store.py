"""The artifact store: one folder per artifact, a manifest, atomic builds (DESIGN §7).

Layout: `<root>/<kind>/<fingerprint[:16]>/` holds the data files and `manifest.json`. A build happens
in `<root>/.incomplete/<kind>-<fp16>-<pid>/` and is renamed into place only after the manifest is
written, so an interrupted build leaves no artifact behind; leftovers of dead processes are removed
the next time the store builds. A folder without a valid manifest is not an artifact, but it is never
deleted either: it is reported as damaged (`damaged`, `artifacts verify`) and a forced rebuild moves it
to `<root>/.damaged/`. Builds of one fingerprint are serialised by a per-fingerprint file lock, so a
second process waits and then finds the artifact built.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import subprocess
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, TypeVar

from filelock import FileLock, Timeout

from fftool import __version__
from fftool.artifacts.hashing import canonical_json, fingerprint, sha256_file
from fftool.artifacts.schema import COMMANDS, VERSIONS
from fftool.errors import ArtifactMissing, FftoolError, IntegrityError, SchemaError
from fftool.outputs import replacing_file
from fftool.ui import log, warn

MANIFEST = "manifest.json"
_INCOMPLETE = ".incomplete"
_SCRATCH = ".scratch"  # survives failed builds: resumable training checkpoints live here
_LOCKS = ".locks"
_DAMAGED = ".damaged"  # unreadable folders a forced rebuild replaced, damaged checkpoints: kept for the user
_KIND = re.compile(r"[a-z][a-z0-9_]*")
_FP_DIR_LEN = 16
_FP_DIR = re.compile(rf"[0-9a-f]{{{_FP_DIR_LEN}}}")  # artifact folders; anything else (reports) is not one
ENV_ROOT = "FFTOOL_ARTIFACTS"


def default_root() -> Path:
    """`$FFTOOL_ARTIFACTS` or `./artifacts`."""
    return Path(os.environ.get(ENV_ROOT, "artifacts"))


@dataclass(frozen=True)
class Manifest:
    """Everything needed to trust, reproduce and locate an artifact."""

    kind: str
    schema_version: int
    fingerprint: str
    params: dict[str, Any]
    inputs: dict[str, str]
    files: dict[str, dict[str, Any]]
    stats: dict[str, Any] = field(default_factory=dict)
    fftool_version: str = __version__
    git_commit: str | None = None
    created_at: str = ""
    # The artifacts it was built from (kind -> fingerprint); `inputs` may name a view of one instead
    # (e.g. `forces[f_dr,speed0]`). Empty in manifests written before views existed: see `built_from`.
    sources: dict[str, str] = field(default_factory=dict)
    # Where it was built (not fingerprinted): trained numbers depend on the torch version, thread count
    # and CPU, so the same inputs and seed give the same numbers only where these match.
    environment: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2, sort_keys=True)

    def threads(self) -> int:
        """The torch threads its build ran on (per rank): from the stats (trained and evaluated artifacts
        record them), else from the environment (recorded whenever the building process had imported
        torch), else 1."""
        return int(self.stats.get("torch_threads") or self.environment.get("torch_threads") or 1)

    def ranks(self) -> int:
        """The processes its build ran on (torchrun's world size; 1 without torchrun)."""
        return int(self.stats.get("world_size") or 1)

    def thread_seconds(self) -> float:
        """What its build cost in CPU time: `build_seconds` times the torch threads and ranks it ran on."""
        return float(self.stats.get("build_seconds") or 0.0) * self.threads() * self.ranks()

    def built_from(self) -> dict[str, str]:
        """The upstream artifacts (kind -> fingerprint) it was built from; raw files are not listed."""
        return self.sources or {kind: fp for kind, fp in self.inputs.items() if _KIND.fullmatch(kind)}

    @classmethod
    def from_json(cls, text: str) -> Manifest:
        """Parse a manifest; ValueError says what is wrong (not JSON, keys missing, unknown keys)."""
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"not JSON ({exc})") from None
        if not isinstance(data, dict):
            raise ValueError("not a JSON object")
        missing = {"kind", "schema_version", "fingerprint", "params", "inputs", "files"} - set(data)
        if missing:
            raise ValueError(f"missing keys {sorted(missing)}")
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            version = data.get("fftool_version", "unknown")
            raise ValueError(f"unknown keys {sorted(unknown)} (written by fftool {version}, this is {__version__})")
        return cls(**data)


@dataclass(frozen=True)
class Artifact:
    """A complete artifact on disk."""

    path: Path
    manifest: Manifest

    @property
    def kind(self) -> str:
        return self.manifest.kind

    @property
    def fingerprint(self) -> str:
        return self.manifest.fingerprint

    @property
    def id(self) -> str:
        return f"{self.kind}/{self.fingerprint[:_FP_DIR_LEN]}"

    @property
    def label(self) -> str:
        """What the artifact is about, for listings: its benchmark, variant and protocol (a report: its profile)
        where it has them."""
        manifest = self.manifest
        keys = ("benchmark", "variant", "protocol", "profile")
        parts = [manifest.stats.get(key) or manifest.params.get(key) for key in keys]
        return " · ".join(str(part) for part in parts if part and part != "none")

    def file(self, name: str) -> Path:
        """Path of one of the artifact's files; fails if the manifest does not list it."""
        if name not in self.manifest.files:
            raise IntegrityError(f"artifact {self.id} has no file {name!r} (files: {sorted(self.manifest.files)})")
        return self.path / name


def _fingerprint_mismatch(manifest: Manifest) -> str | None:
    """What is wrong when a manifest's kind, schema version, parameters and inputs do not give its fingerprint."""
    recorded = fingerprint(manifest.kind, manifest.schema_version, manifest.params, manifest.inputs)
    if recorded == manifest.fingerprint:
        return None
    return (
        f"its parameters and inputs give fingerprint {recorded[:_FP_DIR_LEN]}, not the "
        f"{manifest.fingerprint[:_FP_DIR_LEN]} it records"
    )


Planned = tuple[Mapping[str, Any], Mapping[str, str]]  # a build's (params, inputs), as its fingerprint hashes them


def _differences(manifest: Manifest, params: Mapping[str, Any], inputs: Mapping[str, str]) -> str:
    """The parameters and inputs a manifest records other than a planned build's: `params.lr, inputs.windows`."""
    changed = [
        f"{what}.{key}"
        for what, recorded, wanted in (("params", manifest.params, params), ("inputs", manifest.inputs, inputs))
        for key in sorted({*recorded, *wanted})
        if canonical_json(recorded.get(key)) != canonical_json(wanted.get(key))
    ]
    return ", ".join(changed) or "none of its parameters or inputs"


def _git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).parent,
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    if out.returncode != 0:
        return None
    return out.stdout.strip() or None


def environment() -> dict[str, Any]:
    """Python, library versions, torch's thread count and the CPU model of this process."""
    import platform
    import sys

    import numpy

    found: dict[str, Any] = {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "numpy": numpy.__version__,
    }
    torch = sys.modules.get("torch")  # only when this process uses it: importing torch costs seconds
    if torch is not None:
        found |= {"torch": torch.__version__, "torch_threads": torch.get_num_threads()}
    return found


def _cpu_model() -> str:
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    import platform

    return platform.processor() or platform.machine()


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_empty(folder: Path) -> None:
    with contextlib.suppress(OSError):
        folder.rmdir()


def _hash_files(folder: Path) -> dict[str, dict[str, Any]]:
    files = {}
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        name = path.relative_to(folder).as_posix()
        if name != MANIFEST:
            files[name] = {"sha256": sha256_file(path), "bytes": path.stat().st_size}
    return files


@dataclass
class BuildContext:
    """What a build writes into (`dir`), keeps across attempts (`scratch`) and reports (`stats`)."""

    dir: Path
    scratch: Path  # kept when a build fails (resume state); removed once the artifact is installed
    stats: dict[str, Any] = field(default_factory=dict)
    artifact: Artifact | None = None


C = TypeVar("C", bound=BuildContext)


class ArtifactStore:
    """Fingerprint-addressed, atomically written artifact folders under one root."""

    def __init__(self, root: Path | str) -> None:
        self.root = Path(root)
        self._locks: dict[Path, FileLock] = {}
        self._fresh = not self.root.exists()  # a root this store creates is removed again if nothing lands

    def path_for(self, kind: str, fp: str) -> Path:
        return self.root / kind / fp[:_FP_DIR_LEN]

    def read(self, folder: Path) -> Artifact:
        """The artifact in one of this store's folders; an IntegrityError naming the folder when it is damaged."""
        return self._read(folder)

    def _read(self, folder: Path, planned: Planned | None = None) -> Artifact:
        """The artifact in `folder`; IntegrityError naming the folder when its manifest cannot be read or does not
        give its own fingerprint (naming the fields that differ from a `planned` build's, when given)."""
        try:
            text = (folder / MANIFEST).read_text()
        except (OSError, UnicodeDecodeError) as exc:
            raise IntegrityError(f"{folder}: no readable {MANIFEST} ({exc.__class__.__name__})") from None
        try:
            manifest = Manifest.from_json(text)
        except (ValueError, TypeError) as exc:
            raise IntegrityError(f"{folder / MANIFEST}: not an fftool manifest ({exc})") from None
        if folder.name != manifest.fingerprint[:_FP_DIR_LEN] or folder.parent.name != manifest.kind:
            raise IntegrityError(
                f"{folder}: its manifest describes {manifest.kind}/{manifest.fingerprint[:_FP_DIR_LEN]}, "
                "not this folder"
            )
        mismatch = _fingerprint_mismatch(manifest)
        if mismatch:
            fields = "" if planned is None else f" ({_differences(manifest, *planned)} differ from this build's)"
            raise IntegrityError(
                f"{folder / MANIFEST}: {mismatch}{fields}: the manifest was edited, or copied from another artifact, "
                "so the folder is not trusted"
            )
        return Artifact(folder, manifest)

    def lookup(self, kind: str, fp: str, planned: Planned | None = None) -> Artifact | None:
        """The complete artifact for (kind, fp), or None if there is none; `planned`: the (params, inputs) the
        caller computed fp from, named in the error when the folder's manifest records others.

        A folder at that place whose manifest cannot be read raises IntegrityError and is left as it is:
        it may be a user's file, or an artifact of a newer fftool.
        """
        folder = self.path_for(kind, fp)
        if not folder.exists():
            return None
        artifact = self._read(folder, planned)
        if artifact.fingerprint != fp:
            raise IntegrityError(f"{folder}: holds fingerprint {artifact.fingerprint[:24]}…, expected {fp[:24]}…")
        return artifact

    def _folders(self, kind: str | None) -> Iterator[Path]:
        if not self.root.is_dir():
            return
        kinds = [self.root / kind] if kind else sorted(p for p in self.root.iterdir() if p.is_dir())
        for kind_dir in kinds:
            if not _KIND.fullmatch(kind_dir.name) or not kind_dir.is_dir():
                continue
            yield from sorted(f for f in kind_dir.iterdir() if f.is_dir() and _FP_DIR.fullmatch(f.name))

    def list(self, kind: str | None = None) -> list[Artifact]:
        """Every complete artifact (of one kind if given), oldest first; damaged folders are skipped."""
        found = []
        for folder in self._folders(kind):
            with contextlib.suppress(IntegrityError):
                found.append(self._read(folder))
        return sorted(found, key=lambda a: (a.manifest.created_at, a.id))

    def damaged(self, kind: str | None = None) -> list[IntegrityError]:
        """One error per folder under the root that looks like an artifact but cannot be read."""
        problems = []
        for folder in self._folders(kind):
            try:
                self._read(folder)
            except IntegrityError as exc:
                problems.append(exc)
        return problems

    def resolve(self, ref: str) -> Artifact:
        """Find an artifact by `kind/fp-prefix`, a bare fingerprint prefix, or `kind` when only one exists."""
        kind, _, prefix = ref.rpartition("/") if "/" in ref else ("", "", ref)
        if ("/" in ref and not _KIND.fullmatch(kind)) or (prefix and not re.fullmatch(r"[a-z0-9_]+", prefix)):
            raise FftoolError(f"{ref!r} is not an artifact id (kind/fingerprint-prefix, e.g. windows/3f9c2a)")
        candidates = self.list(kind or None)
        if kind and not prefix:
            matches = candidates
        else:
            matches = [a for a in candidates if a.fingerprint.startswith(prefix)]
            if not kind and not matches and _KIND.fullmatch(prefix):  # a bare kind name
                matches = self.list(prefix)
        if not matches:
            raise ArtifactMissing(f"no artifact matches {ref!r} under {self.root} (see `fftool artifacts list`)")
        if len(matches) > 1:
            ids = ", ".join(f"{a.id} ({a.label})" if a.label else a.id for a in matches)
            raise FftoolError(
                f"{ref!r} is ambiguous, {len(matches)} artifacts match: {ids}; give more of the fingerprint"
            )
        return matches[0]

    @classmethod
    def open(cls, ref: str | Path, root: Path | None = None) -> tuple[ArtifactStore, Artifact]:
        """An artifact by id (`cvae/3f9c2a`, under `root` or the default root) or by its folder (in the store
        that holds the folder), with its store."""
        folder = Path(ref)
        if folder.is_dir() and (folder / MANIFEST).is_file():
            folder = folder.resolve()
            store = cls(folder.parent.parent)
            return store, store.resolve(f"{folder.parent.name}/{folder.name}")
        store = cls(root or default_root())
        return store, store.resolve(str(ref))

    def require(self, kind: str, fp: str, schema_version: int, made_by: str) -> Artifact:
        """The artifact a stage reads; a clear error naming the command that makes it otherwise."""
        artifact = self.lookup(kind, fp)
        if artifact is None:
            raise ArtifactMissing(
                f"no {kind!r} artifact for these parameters (fingerprint {fp[:_FP_DIR_LEN]}) "
                f"under {self.root}; run `{made_by}` first, with the same -c/--set"
            )
        check_schema(artifact, kind, schema_version, made_by)
        return artifact

    def verify(self, artifact: Artifact) -> list[str]:
        """Re-hash the artifact's files and recompute its fingerprint from its manifest; one line per file that
        changed, vanished or appeared, and one if the manifest's parameters and inputs do not give its
        fingerprint."""
        mismatch = _fingerprint_mismatch(artifact.manifest)
        problems = [f"{MANIFEST}: {mismatch}"] if mismatch else []
        on_disk = _hash_files(artifact.path)
        for name, expected in artifact.manifest.files.items():
            actual = on_disk.pop(name, None)
            if actual is None:
                problems.append(f"{name}: missing")
            elif actual["sha256"] != expected["sha256"]:
                problems.append(
                    f"{name}: content changed (sha256 {actual['sha256'][:12]}…, manifest {expected['sha256'][:12]}…)"
                )
        problems.extend(f"{name}: not listed in the manifest" for name in on_disk)
        for folder, dirs, files in os.walk(artifact.path):  # never follows a link, so a loop ends
            links = [n for n in (*dirs, *files) if (Path(folder) / n).is_symlink()]
            problems.extend(f"{(Path(folder) / n).relative_to(artifact.path)}: a link, not a file" for n in links)
        return problems

    def check_inputs(self, artifacts: Mapping[str, Artifact], made_by: Mapping[str, str] = COMMANDS) -> None:
        """Refuse to build from (or read) artifacts whose files changed since they were built.

        `made_by` names the command that rebuilds each input (default: its kind's, schema.COMMANDS); the error
        names the artifact and the file.
        """
        for name, artifact in artifacts.items():
            problems = self.verify(artifact)
            if problems:
                more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
                raise IntegrityError(
                    f"artifact {artifact.id} ({artifact.path}) changed since it was built: {problems[0]}{more}; "
                    f"nothing was built from it or read. Rebuild it with `{made_by.get(name, 'fftool')} --force`"
                )

    def chain(self, artifact: Artifact) -> list[Artifact | str]:
        """The artifact and every artifact it was built from, depth first; a missing input is a message."""
        found: list[Artifact | str] = [artifact]
        for kind, fp in artifact.manifest.built_from().items():
            upstream = self.lookup(kind, fp)
            if upstream is None:
                found.append(f"{kind}/{fp[:_FP_DIR_LEN]} (an input of {artifact.id}) is no longer in the store")
            else:
                found.extend(item for item in self.chain(upstream) if item not in found)
        return found

    def _lock_path(self, kind: str, fp: str) -> Path:
        return self.root / _LOCKS / f"{kind}-{fp[:_FP_DIR_LEN]}.lock"

    @contextlib.contextmanager
    def lock(self, kind: str, fp: str) -> Iterator[None]:
        """Hold the per-fingerprint lock builds take (re-entrant in a process); say so when another holds it."""
        path = self._lock_path(kind, fp)
        lock = self._locks.setdefault(path, FileLock(path))  # filelock creates the folder when it first acquires
        try:
            lock.acquire(timeout=0)
        except Timeout:
            log(f"{kind}/{fp[:_FP_DIR_LEN]}: another fftool process is building it - waiting")
            lock.acquire()
        try:
            yield
        finally:
            lock.release()

    def clean_incomplete(self) -> list[Path]:
        """Remove build folders whose process has died (a killed build leaves one behind)."""
        removed = []
        tmp_root = self.root / _INCOMPLETE
        if tmp_root.is_dir():
            for folder in tmp_root.iterdir():
                pid_text = folder.name.rsplit("-", 1)[-1]
                if not pid_text.isdigit() or not _pid_alive(int(pid_text)):
                    shutil.rmtree(folder, ignore_errors=True)
                    removed.append(folder)
        return removed

    @contextlib.contextmanager
    def build(
        self,
        kind: str,
        fp: str,
        *,
        schema_version: int,
        params: Mapping[str, Any],
        inputs: Mapping[str, str],
        sources: Mapping[str, str] | None = None,
        context: Callable[[Path, Path], C] = BuildContext,  # type: ignore[assignment]
    ) -> Iterator[C]:
        """Build an artifact atomically: write into `ctx.dir`, set `ctx.stats`; rename on success.

        `context(dir, scratch)` makes the yielded context: a plain `BuildContext`, or a richer one (the
        stages' `StageContext`) that carries how the build runs and reports.

        Holds the fingerprint's lock throughout, so builds of one fingerprint never overlap. On any
        exception (KeyboardInterrupt included) the temporary folder is removed and an existing artifact
        at the destination is left untouched.
        """
        try:
            with self.lock(kind, fp):
                yield from self._build_locked(kind, fp, schema_version, params, inputs, sources or {}, context)
        finally:
            if self._fresh and not self.path_for(kind, fp).exists():  # a failed first build leaves no trace
                lock_path = self._lock_path(kind, fp)
                lock_path.unlink(missing_ok=True)
                for folder in (lock_path.parent, self.root):
                    _remove_empty(folder)

    def _build_locked(
        self,
        kind: str,
        fp: str,
        schema_version: int,
        params: Mapping[str, Any],
        inputs: Mapping[str, str],
        sources: Mapping[str, str],
        context: Callable[[Path, Path], C],
    ) -> Iterator[C]:
        self.clean_incomplete()
        tmp = self.root / _INCOMPLETE / f"{kind}-{fp[:_FP_DIR_LEN]}-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        ctx = context(tmp, self.root / _SCRATCH / f"{kind}-{fp[:_FP_DIR_LEN]}")
        try:
            yield ctx
            manifest = Manifest(
                kind=kind,
                schema_version=schema_version,
                fingerprint=fp,
                params=dict(params),
                inputs=dict(inputs),
                sources=dict(sources),
                files=_hash_files(tmp),
                stats=ctx.stats,
                git_commit=_git_commit(),
                created_at=datetime.now(timezone.utc).isoformat(timespec="seconds"),
                environment=environment(),
            )
            (tmp / MANIFEST).write_text(manifest.to_json())
            self._install(tmp, self.path_for(kind, fp))
            self._keep_damaged(ctx.scratch)
            shutil.rmtree(ctx.scratch, ignore_errors=True)
            _remove_empty(ctx.scratch.parent)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
            _remove_empty(tmp.parent)
        ctx.artifact = Artifact(self.path_for(kind, fp), manifest)

    def adopt(self, artifact: Artifact, manifest: Manifest | None = None) -> Artifact:
        """Copy an artifact of another store into this one (under `manifest`, default its own), atomically and
        under its fingerprint's lock; the copy's files are checked against the manifest before it lands."""
        manifest = manifest or artifact.manifest
        final = self.path_for(manifest.kind, manifest.fingerprint)
        with self.lock(manifest.kind, manifest.fingerprint):
            self.clean_incomplete()
            tmp = self.root / _INCOMPLETE / f"{manifest.kind}-{manifest.fingerprint[:_FP_DIR_LEN]}-{os.getpid()}"
            shutil.rmtree(tmp, ignore_errors=True)
            try:
                shutil.copytree(artifact.path, tmp)
                (tmp / MANIFEST).write_text(manifest.to_json())
                problems = self.verify(Artifact(tmp, manifest))
                if problems:
                    raise IntegrityError(f"{artifact.path}: {problems[0]}; nothing was copied")
                self._install(tmp, final)
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
                _remove_empty(tmp.parent)
        return Artifact(final, manifest)

    def replace_manifest(self, artifact: Artifact, manifest: Manifest) -> Artifact:
        """Rewrite one of this store's artifacts' manifest where only its stats change (what it records about
        the build, never what its fingerprint or files are), atomically under its lock."""
        old = self._read(artifact.path).manifest
        if replace(manifest, stats=old.stats) != old:
            raise IntegrityError(f"{artifact.path}: a new manifest may change only the stats")
        with self.lock(old.kind, old.fingerprint), replacing_file(artifact.path / MANIFEST) as partial:
            partial.write_text(manifest.to_json())
        return Artifact(artifact.path, manifest)

    def remove(self, artifact: Artifact) -> None:
        """Delete one of this store's own artifacts (a readable one: anything else is left where it is)."""
        self._read(artifact.path)
        if artifact.path.resolve().parent.parent != self.root.resolve():
            raise IntegrityError(f"{artifact.path} is not an artifact of the store under {self.root}")
        shutil.rmtree(artifact.path)
        _remove_empty(artifact.path.parent)

    def _keep_damaged(self, scratch: Path) -> None:
        """Move checkpoints a training set aside as damaged (`*.damaged-*`) out of the scratch folder."""
        for damaged in sorted(scratch.glob("*.damaged-*")):
            aside = self.root / _DAMAGED / f"{scratch.name}-{damaged.name}"
            aside.parent.mkdir(parents=True, exist_ok=True)
            os.replace(damaged, aside)

    def _install(self, tmp: Path, final: Path) -> None:
        """Move a finished build into place; what it replaces is deleted only if it is a readable artifact."""
        final.parent.mkdir(parents=True, exist_ok=True)
        if not final.exists():
            os.replace(tmp, final)
            return
        try:
            self._read(final)
            aside, readable = tmp.with_name(tmp.name + "-old"), True
        except IntegrityError:  # not ours to delete: keep it where the user can find it
            stamp = time.strftime("%Y%m%dT%H%M%S")
            aside, readable = self.root / _DAMAGED / f"{final.parent.name}-{final.name}-{stamp}-{os.getpid()}", False
            aside.parent.mkdir(parents=True, exist_ok=True)
        os.replace(final, aside)
        os.replace(tmp, final)
        if readable:
            shutil.rmtree(aside, ignore_errors=True)
        else:
            warn(f"{final} could not be read as an artifact; it was moved to {aside}, not deleted")


def check_schema(artifact: Artifact, kind: str, schema_version: int | None = None, made_by: str | None = None) -> None:
    """Fail clearly when an artifact is not the kind or schema version a reader expects: by default the
    version this fftool writes (schema.VERSIONS), whoever reads it (stages, `predict`, the API)."""
    schema_version = VERSIONS[kind] if schema_version is None else schema_version
    made_by = made_by or COMMANDS.get(kind, "fftool")
    if artifact.kind != kind:
        raise SchemaError(f"artifact {artifact.id} is a {artifact.kind!r} artifact, expected {kind!r}")
    if artifact.manifest.schema_version != schema_version:
        raise SchemaError(
            f"artifact {artifact.id} has schema version {artifact.manifest.schema_version}, this fftool reads "
            f"version {schema_version}; rebuild it with `{made_by} --force`"
        )
