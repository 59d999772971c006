"""`fftool export`: a trained predictor as an ONNX graph and its manifest, for a planner's own runtime."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from fftool.cli.app import RootOption, app, boundary


@app.command(
    epilog="Examples:\n\n"
    "  fftool export cpu/zara1/dr --out zara1_dr/        # a shipped model: its CVAE and goal U-Net\n\n"
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
    out: Annotated[Path, typer.Option("--out", file_okay=False, help="Folder for the graphs and manifest.json.")],
    dlow: Annotated[
        str | None, typer.Option("--dlow", help="The DLow sampler over that CVAE (dlow/…), for an artifact id.")
    ] = None,
    goal_model: Annotated[
        str | None,
        typer.Option(
            "--goal-model",
            help="A goal variant's goal U-Net (goal/…, or a shipped name), exported beside it as goal_unet.onnx; "
            "default: a shipped goal variant's own.",
        ),
    ] = None,
    root: RootOption = None,
) -> None:
    """Export a CVAE to ONNX with how it gets its K codes (a DLow sampler, the prior's mean, or prior draws whose
    standard normal noise is an input), a goal variant's goal U-Net beside it, and a manifest of their inputs,
    units and where they came from. The graph gives the K futures and the most-likely future; a goal variant gets
    a second graph for one known goal per agent (model_one_goal.onnx). Graphs are deterministic: goals, desired
    speeds, groups and any random draws are inputs computed by the host."""
    from fftool import zoo
    from fftool.api import load, load_goal_sampler
    from fftool.export import EXPORT, GOAL_ONNX_FILE, ONE_GOAL_ONNX_FILE, ONNX_FILE
    from fftool.export import export as export_onnx
    from fftool.outputs import check_output
    from fftool.ui import log, progress
    from fftool.variants import reads_goal

    check_output(out, "--out", EXPORT)
    chosen = load(model, root=root, device="cpu", dlow=dlow)
    if goal_model is None and zoo.is_name(model) and reads_goal(chosen.variant):
        goal_model = model
    goals = None if goal_model is None else load_goal_sampler(goal_model, root=root, device="cpu")
    source = {"model": model, **chosen.fingerprints} | ({"goal_model": goal_model} if goal_model else {})
    with progress() as bar:
        bar.add_task("export to ONNX (minutes: the 12 decoding steps are unrolled)", total=None)
        done = export_onnx(chosen, out, source, goals)
    files = [name for name in (ONNX_FILE, ONE_GOAL_ONNX_FILE, GOAL_ONNX_FILE) if (done.folder / name).is_file()]
    size = sum((done.folder / name).stat().st_size for name in files) / 1e6
    log(f"wrote {', '.join(files)} ({size:.1f} MB) and manifest.json to {done.folder}: {done.manifest['variant']}, "
        f"K = {done.manifest['k']}, inputs {', '.join(done.manifest['inputs'])}")  # fmt: skip
