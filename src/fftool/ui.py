"""Terminal output: one stderr console for logs and progress, stdout for results (tables).

Library code reports through `log`/`warn` and `progress`; it never prints errors or exits.
"""

from __future__ import annotations

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

err_console = Console(stderr=True, highlight=False)
out_console = Console(highlight=False)
if not out_console.is_terminal:  # piped or captured: do not squeeze tables into 80 columns
    out_console.width = 120


def log(message: str) -> None:
    """One line on stderr, never broken by rich (the terminal wraps it; a log file keeps it greppable)."""
    err_console.print(message, soft_wrap=True)


def warn(message: str) -> None:
    err_console.print(f"[yellow]warning:[/] {message}", soft_wrap=True)


def progress() -> Progress:
    """A rich progress display on stderr; use as a context manager."""
    return Progress(
        SpinnerColumn(),
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=err_console,
        transient=False,
    )
