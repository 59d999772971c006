"""One root exception and small subclasses; messages say what went wrong and what to do.

The CLI turns every `FftoolError` into `Error: <message>` and exit code 1 (2 for a `UsageError`: the
command line or configuration asked for something fftool refuses). Library code never prints errors or
exits.
"""

from __future__ import annotations

from pathlib import Path


class FftoolError(Exception):
    """Root of every error fftool reports to a user."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message

    def __str__(self) -> str:
        return self.message


class UsageError(FftoolError):
    """The command line asked for something fftool refuses (exit code 2), e.g. an unsafe --out folder."""


class ConfigError(UsageError, ValueError):
    """A configuration key is unknown, has the wrong type or an invalid value."""


class RawDataError(FftoolError, ValueError):
    """A raw input file is missing or malformed; names the file and, where known, the line."""

    def __init__(self, path: Path | str, problem: str, line_no: int | None = None) -> None:
        where = f"{path}:{line_no}" if line_no is not None else f"{path}"
        super().__init__(f"{where}: {problem}")
        self.path = Path(path)
        self.line_no = line_no
        self.problem = problem

    def __reduce__(self) -> tuple[type, tuple[Path, str, int | None]]:
        """Pickled with its own arguments, so a worker process can hand it back (`fftool.scheduler`)."""
        return type(self), (self.path, self.problem, self.line_no)


class ArtifactMissing(FftoolError, FileNotFoundError):
    """A stage needs an artifact that has not been built for these parameters."""


class SchemaError(FftoolError):
    """An artifact has the wrong kind or schema version for the stage that reads it."""


class IntegrityError(FftoolError):
    """An artifact's files no longer match the hashes in its manifest."""


class InputError(FftoolError, ValueError):
    """Input a model cannot take (non-finite or absurd coordinates, a window without agents, a bad k): names
    the batch, agent and step. The API raises it where the CLI prints one line (exit 1)."""


class FetchError(FftoolError):
    """A download failed or its checksum did not match."""
