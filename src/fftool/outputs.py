"""The one way fftool writes a file or folder in place of another: a temporary beside the target, created
exclusively under an unpredictable name (so a link planted there is never followed), renamed over the target
only once it is complete, and removed whatever happens."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
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


def check_place(out: Path, flag: str) -> None:
    """Refuse (UsageError), before any work, an output path that could not be written: one under a file, a
    folder where a file goes, or a link (replacing it would put a file where the user's link was)."""
    from fftool.errors import UsageError

    if out.is_symlink():
        raise UsageError(f"{flag} {out}: a symbolic link; give the file it points to, or a new path")
    if out.is_dir():
        raise UsageError(f"{flag} {out}: a folder; give a file name")
    blocked = next((parent for parent in out.parents if parent.exists() and not parent.is_dir()), None)
    if blocked is not None:
        raise UsageError(f"{flag} {out}: {blocked} is a file, not a folder")
