"""The one way fftool writes a file or folder in place of another: a temporary beside the target, created
exclusively under an unpredictable name (so a link planted there is never followed), renamed over the target
only once it is complete, and removed whatever happens; and the one guard (`check_output`) that decides
whether a user's path may be written at all."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

_UMASK = os.umask(0o022)
os.umask(_UMASK)  # read once: outputs get the permissions a plain open() would give them, not mkstemp's 0600


@contextmanager
def replacing_file(out: Path) -> Iterator[Path]:
    """A fresh empty file in out's folder to write into; it becomes `out` when the block ends without error.
    A link at `out` is replaced, never followed."""
    out.parent.mkdir(parents=True, exist_ok=True)
    handle, name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent)
    os.close(handle)
    partial = Path(name)
    partial.chmod(0o666 & ~_UMASK)
    try:
        yield partial
        os.replace(partial, out)
    finally:
        partial.unlink(missing_ok=True)


@contextmanager
def replacing_folder(out: Path) -> Iterator[Path]:
    """A fresh empty folder beside `out` to fill; it takes out's place when the block ends without error (the
    folder it replaces is removed only after the rename). The caller decides whether `out` may be replaced."""
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent))
    partial.chmod(0o777 & ~_UMASK)
    try:
        yield partial
        old = None
        if out.is_dir() and not out.is_symlink() and not any(out.iterdir()):
            out.rmdir()  # an empty folder made for the output
        elif out.exists() or out.is_symlink():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
            os.replace(out, old / "replaced")
        try:
            partial.rename(out)
        except OSError:
            if old is not None:
                os.replace(old / "replaced", out)
            raise
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(partial, ignore_errors=True)


@dataclass(frozen=True)
class Kind:
    """A kind of output fftool writes where a user points it, and how to tell one fftool wrote: `foreign(out)`
    says what an existing `out` holds that fftool did not write (None: all of it is fftool's)."""

    noun: str  # "a prediction file", "a report folder", ...
    folder: bool
    foreign: Callable[[Path], str | None]


def marked_file(noun: str, is_marked: Callable[[Path], bool]) -> Kind:
    """A file kind recognised by the mark fftool leaves in it (metadata, a comment)."""
    return Kind(noun, False, lambda path: None if is_marked(path) else "exists and was not written by fftool")


def check_output(out: Path, flag: str, kind: Kind) -> None:
    """The one guard of every user-facing writer, before any work and again just before the swap: refuse
    (UsageError) a link (replacing it would put a file where the user's link was), a path under a file, a
    file where a folder goes or the reverse, and anything existing that fftool did not write. An empty folder
    may become a folder output."""
    from fftool.errors import UsageError

    where = f"{flag} {out}"
    if out.is_symlink():
        raise UsageError(f"{where}: a symbolic link; give the path it points to, or a new one")
    blocked = next((parent for parent in out.parents if parent.exists() and not parent.is_dir()), None)
    if blocked is not None:
        raise UsageError(f"{where}: {blocked} is a file, not a folder")
    if kind.folder and out.exists() and not out.is_dir():
        raise UsageError(f"{where}: a file; give a folder")
    if not kind.folder and out.is_dir():
        raise UsageError(f"{where}: a folder; give a file name")
    if not out.exists() or (kind.folder and not any(out.iterdir())):
        return
    problem = kind.foreign(out)
    if problem is not None:
        raise UsageError(
            f"{where}: {problem}; fftool replaces only {kind.noun} it wrote, refusing to overwrite it "
            "(move those files out or give another path)"
        )
