"""The `fftool` command line: thin commands over the stages, the engine and the reports.

`fftool.cli.app` holds the Typer app, the one error boundary and the shared options; each module adds
its commands: `data` (fetch-data), `stages` (one per pipeline stage), `predict` (your own tracks), `export`
(ONNX), `reports`
(reproduce/ablate, plot, rescore), `artifacts` (list, show, verify) and `models` (the shipped models).
The science lives in the packages below.
"""

from importlib import import_module

from fftool.cli.app import app

# Importing registers the commands, in this order.
for _module in ("data", "stages", "predict", "export", "reports", "artifacts", "models"):
    import_module(f"fftool.cli.{_module}")

__all__ = ["app"]
