"""`python -m fftool` runs the CLI."""

from fftool.cli import app

app()
