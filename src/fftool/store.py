"""The artifact store: one folder per artifact, a manifest, atomic builds (DESIGN §7).

Layout: `<root>/<kind>/<fingerprint[:16]>/` holds the data files and `manifest.json`. A build happens
in `<root>/.incomplete/<kind>-<fp16>-<pid>/` and is renamed into place only after the manifest is
written, so an interrupted build leaves no artifact behind; leftovers of dead processes are removed
the next time the store builds. A folder without a valid manifest is not an artifact.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
from collections.abc import Iterator, Mapping
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from fftool import __version__
from fftool.errors import ArtifactMissing, FftoolError, IntegrityError, SchemaError
from fftool.hashing import sha256_file

MANIFEST = "manifest.json"
_INCOMPLETE = ".incomplete"
_SCRATCH = ".scratch"  # survives failed builds: resumable training checkpoints live here
_FP_DIR_LEN = 16
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

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> Manifest:
        data = json.loads(text)
        missing = {"kind", "schema_version", "fingerprint", "params", "inputs", "files"} - set(data)
        if missing:
            raise ValueError(f"missing keys {sorted(missing)}")
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

    def file(self, name: str) -> Path:
        """Path of one of the artifact's files; fails if the manifest does not list it."""
        if name not in self.manifest.files:
            raise IntegrityError(f"artifact {self.id} has no file {name!r} (files: {sorted(self.manifest.files)})")
        return self.path / name


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


class ArtifactStore:
    """Fingerprint-addressed, atomically written artifact folders under one root."""

    def __init__(self, root: Path | str) -> None:
        self.root = Path(root)

    def path_for(self, kind: str, fp: str) -> Path:
        return self.root / kind / fp[:_FP_DIR_LEN]

    def _read(self, folder: Path) -> Artifact | None:
        try:
            return Artifact(folder, Manifest.from_json((folder / MANIFEST).read_text()))
        except (OSError, ValueError, TypeError):
            return None

    def lookup(self, kind: str, fp: str) -> Artifact | None:
        """The complete artifact for (kind, fp), or None. A folder with a corrupt manifest is removed."""
        folder = self.path_for(kind, fp)
        if not folder.exists():
            return None
        artifact = self._read(folder)
        if artifact is None or artifact.fingerprint != fp or artifact.kind != kind:
            shutil.rmtree(folder, ignore_errors=True)
            return None
        return artifact

    def list(self, kind: str | None = None) -> list[Artifact]:
        """Every complete artifact (of one kind if given), oldest first."""
        if not self.root.exists():
            return []
        kinds = [self.root / kind] if kind else sorted(p for p in self.root.iterdir() if p.is_dir())
        found = []
        for kind_dir in kinds:
            if kind_dir.name.startswith(".") or not kind_dir.is_dir():
                continue
            for folder in sorted(kind_dir.iterdir()):
                artifact = self._read(folder) if folder.is_dir() else None
                if artifact is not None:
                    found.append(artifact)
        return sorted(found, key=lambda a: (a.manifest.created_at, a.id))

    def resolve(self, ref: str) -> Artifact:
        """Find an artifact by `kind/fp-prefix`, `kind` (the newest) or a bare fingerprint prefix."""
        kind, _, prefix = ref.rpartition("/") if "/" in ref else ("", "", ref)
        candidates = self.list(kind or None)
        if kind and not prefix:
            matches = candidates[-1:]
        else:
            matches = [a for a in candidates if a.fingerprint.startswith(prefix)]
            if not kind and not matches:  # a bare kind name: its newest artifact
                matches = self.list(prefix)[-1:] if (self.root / prefix).is_dir() else []
        if not matches:
            raise ArtifactMissing(f"no artifact matches {ref!r} under {self.root} (see `fftool artifacts list`)")
        if len(matches) > 1:
            ids = ", ".join(a.id for a in matches)
            raise FftoolError(f"{ref!r} is ambiguous: {ids}; give more of the fingerprint")
        return matches[0]

    def require(self, kind: str, fp: str, schema_version: int, made_by: str) -> Artifact:
        """The artifact a stage reads; a clear error naming the command that makes it otherwise."""
        artifact = self.lookup(kind, fp)
        if artifact is None:
            raise ArtifactMissing(
                f"no {kind!r} artifact for these parameters (fingerprint {fp[:_FP_DIR_LEN]}) "
                f"under {self.root}; run `{made_by}` first"
            )
        check_schema(artifact, kind, schema_version, made_by)
        return artifact

    def verify(self, artifact: Artifact) -> list[str]:
        """Re-hash the artifact's files; return one line per file that changed, vanished or appeared."""
        problems = []
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
        return problems

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
    ) -> Iterator[BuildContext]:
        """Build an artifact atomically: write into `ctx.dir`, set `ctx.stats`; rename on success.

        On any exception (KeyboardInterrupt included) the temporary folder is removed and an existing
        artifact at the destination is left untouched.
        """
        self.clean_incomplete()
        created_root = not self.root.exists()
        tmp = self.root / _INCOMPLETE / f"{kind}-{fp[:_FP_DIR_LEN]}-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        ctx = BuildContext(dir=tmp, scratch=self.root / _SCRATCH / f"{kind}-{fp[:_FP_DIR_LEN]}")
        try:
            yield ctx
            manifest = Manifest(
                kind=kind,
                schema_version=schema_version,
                fingerprint=fp,
                params=dict(params),
                inputs=dict(inputs),
                files=_hash_files(tmp),
                stats=ctx.stats,
                git_commit=_git_commit(),
                created_at=datetime.now(timezone.utc).isoformat(timespec="seconds"),
            )
            (tmp / MANIFEST).write_text(manifest.to_json())
            self._install(tmp, self.path_for(kind, fp))
            shutil.rmtree(ctx.scratch, ignore_errors=True)
            _remove_empty(ctx.scratch.parent)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
            _remove_empty(tmp.parent)
            if created_root:
                _remove_empty(self.root)  # a failed first build leaves no trace at all
        ctx.artifact = Artifact(self.path_for(kind, fp), manifest)

    def _install(self, tmp: Path, final: Path) -> None:
        final.parent.mkdir(parents=True, exist_ok=True)
        if final.exists():  # a forced rebuild: move the old one aside, swap, then delete it
            trash = tmp.with_name(tmp.name + "-old")
            os.replace(final, trash)
            os.replace(tmp, final)
            shutil.rmtree(trash, ignore_errors=True)
        else:
            os.replace(tmp, final)


@dataclass
class BuildContext:
    """What a build writes into (`dir`), keeps across attempts (`scratch`) and reports (`stats`)."""

    dir: Path
    scratch: Path  # kept when a build fails (resume state); removed once the artifact is installed
    stats: dict[str, Any] = field(default_factory=dict)
    artifact: Artifact | None = None


def check_schema(artifact: Artifact, kind: str, schema_version: int, made_by: str) -> None:
    """Fail clearly when an artifact is not the kind or schema version a reader expects."""
    if artifact.kind != kind:
        raise SchemaError(f"artifact {artifact.id} is a {artifact.kind!r} artifact, expected {kind!r}")
    if artifact.manifest.schema_version != schema_version:
        raise SchemaError(
            f"artifact {artifact.id} has schema version {artifact.manifest.schema_version}, this fftool reads "
            f"version {schema_version}; rebuild it with `{made_by} --force`"
        )
