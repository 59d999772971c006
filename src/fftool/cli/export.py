"""`fftool export`: a trained predictor as an ONNX graph and its manifest, for a planner's own runtime."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from fftool.cli.app import RootOption, app, boundary


@app.command(
    epilog="Examples:\n\n"
    "  fftool export cpu/zara1/dr --out zara1_dr/        # a shipped model: its CVAE with its DLow sampler\n\n"
    "  fftool export dlow/8e1b07 --out mine/                # a DLow sampler you trained, over its CVAE"
)
@boundary
def export(
    model: Annotated[
        str,
        typer.Argument(
            help="A shipped model's name (cpu/zara1/dr), a DLow sampler's artifact id or folder (with its CVAE), "
            "or a CVAE's (with --dlow)."
        ),
    ],
    out: Annotated[Path, typer.Option("--out", file_okay=False, help="Folder for model.onnx and manifest.json.")],
    dlow: Annotated[
        str | None, typer.Option("--dlow", help="The DLow sampler over that CVAE (dlow/…), for an artifact id.")
    ] = None,
    root: RootOption = None,
) -> None:
    """Export a CVAE and its DLow sampler to ONNX (deterministic K futures; goals, desired speeds and groups are
    inputs computed by the host), with a manifest of its inputs, units and where it came from."""
    from fftool.api import load
    from fftool.export import ONNX_FILE, check_out
    from fftool.export import export as export_onnx
    from fftool.ui import log, progress

    check_out(out)
    chosen = load(model, root=root, device="cpu", dlow=dlow)
    source = {"model": model, **chosen.fingerprints}
    with progress() as bar:
        bar.add_task("export to ONNX (minutes: the 12 decoding steps are unrolled)", total=None)
        done = export_onnx(chosen, out, source)
    size = (done.folder / ONNX_FILE).stat().st_size / 1e6
    log(f"wrote {done.folder}/{ONNX_FILE} ({size:.1f} MB) and manifest.json: {done.manifest['variant']}, K = "
        f"{done.manifest['k']}, inputs {', '.join(done.manifest['inputs'])}")  # fmt: skip
