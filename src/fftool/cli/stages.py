"""One thin command per pipeline stage: resolve the configuration, build the stage, print its table."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from fftool.cli.app import (
    BenchmarksOption,
    ConfigOption,
    DeviceOption,
    ForceOption,
    ProtocolOption,
    RootOption,
    SetOption,
    app,
    boundary,
    build_stages,
    check_predictor,
    check_variant,
    run_stages,
)
from fftool.dataset.scenes import BENCHMARKS


@app.command(
    epilog="Examples:\n\n  fftool ingest --raw ../shared/data/eth_ucy/raw --root artifacts\n\n"
    "  fftool ingest --dataset crowd/dataset.toml --root artifacts-crowd   # your own dataset (docs/data.md)"
)
@boundary
def ingest(
    raw: Annotated[
        Path | None,
        typer.Option(
            "--raw",
            exists=True,
            file_okay=False,
            help="Raw Social-GAN root with all_data/, train/, val/. Default: data.raw_dir of the config.",
        ),
    ] = None,
    dataset: Annotated[
        Path | None,
        typer.Option(
            "--dataset",
            exists=True,
            dir_okay=False,
            help="A dataset TOML (docs/data.md): its files instead of ETH/UCY. Default: data.dataset of the config.",
        ),
    ] = None,
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    force: ForceOption = False,
) -> None:
    """Validate the raw ETH/UCY files (or a dataset's) and build the tracks and windows artifacts, with a summary."""
    from fftool.reporting.summaries import windows_summary_table
    from fftool.ui import out_console

    values = {"data.raw_dir": str(raw)} if raw else {}
    if dataset:
        values["data.dataset"] = str(dataset)
    built = run_stages(["tracks", "windows"], config, set_, root, force, values=values)
    out_console.print(windows_summary_table(built["windows"]))


@app.command(
    epilog="Examples:\n\n  fftool forces\n\n"
    "  fftool forces --explain zara1 100 --out figures/forces_zara1_100.png   # zara1, frame 100"
)
@boundary
def forces(
    explain: Annotated[
        tuple[str, int] | None,
        typer.Option(
            "--explain",
            metavar="SCENE FRAME",
            help=f"Also draw the test window of SCENE ({', '.join(BENCHMARKS)}) whose last observed "
            "frame id is FRAME, with its forces, over the scene image.",
        ),
    ] = None,
    source: Annotated[
        str | None, typer.Option("--source", help="With --explain on univ: students001 or students003.")
    ] = None,
    out: Annotated[
        Path | None, typer.Option("--out", help="PNG path for --explain. Default: SCENE_FRAME_forces.png.")
    ] = None,
    device: DeviceOption = "auto",
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    force: ForceOption = False,
) -> None:
    """Compute driving and repulsive social forces for every valid agent-window, with a summary table."""
    from fftool.config import load_config
    from fftool.reporting.summaries import forces_summary_table
    from fftool.ui import log, out_console

    built = run_stages(["forces"], config, set_, root, force, device)
    out_console.print(forces_summary_table(built["forces"]))
    if explain:
        from fftool.reporting.explain import explain_window

        scene, frame = explain
        png = explain_window(
            scene=scene,
            frame_id=frame,
            out=out or Path(f"{scene}_{frame}_forces.png"),
            windows=built["windows"],
            forces=built["forces"],
            tracks=built["tracks"],
            scenes_dir=Path(load_config(config, list(set_ or [])).data.scenes_dir),
            source=source,
        )
        log(f"wrote {png}")


@app.command(epilog="Example: fftool maps --set maps.resolution_m=0.25")
@boundary
def maps(
    config: ConfigOption = None, set_: SetOption = None, root: RootOption = None, force: ForceOption = False
) -> None:
    """Warp each scene image onto a metric ground grid and derive semantic channels (with check PNGs)."""
    from fftool.reporting.summaries import maps_table
    from fftool.ui import out_console

    out_console.print(maps_table(run_stages(["maps"], config, set_, root, force)["maps"]))


@app.command(
    "train-goal",
    epilog="Examples:\n\n  fftool train-goal --benchmarks zara1,zara2 --config pipelines/quick.toml\n\n"
    "  torchrun --standalone --nproc-per-node 2 -m fftool train-goal --config pipelines/quick.toml"
    "   # data-parallel, 2 ranks (docs/scaling.md)",
)
@boundary
def train_goal(
    benchmarks: BenchmarksOption = "zara1",
    device: DeviceOption = "auto",
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    force: ForceOption = False,
) -> None:
    """Train the U-Net goal estimator on each benchmark's train part (resumable; best epoch by val goal-FDE)."""
    from fftool.learning.distributed import leader
    from fftool.reporting.summaries import training_table
    from fftool.ui import out_console

    for benchmark in benchmarks.split(","):
        built = run_stages(["goal"], config, set_, root, force, device, benchmark)
        if leader():  # under torchrun, rank 0 alone prints
            out_console.print(training_table(built["goal"], f"goal U-Net ({benchmark})"))


@app.command(
    "sample-goals", epilog="Example: fftool sample-goals --benchmarks zara1,zara2 --config pipelines/quick.toml"
)
@boundary
def sample_goals(
    benchmarks: BenchmarksOption = "all",
    device: DeviceOption = "auto",
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    force: ForceOption = False,
) -> None:
    """Sample K goals per agent-window with trained goal U-Nets; table of goal-FDE@K vs anchors and CV."""
    from fftool.reporting.summaries import goal_fde_table
    from fftool.ui import out_console

    artifacts = {
        benchmark: run_stages(["goals"], config, set_, root, force, device, benchmark)["goals"]
        for benchmark in benchmarks.split(",")
    }
    out_console.print(goal_fde_table(artifacts))


VariantOption = Annotated[
    str,
    typer.Option(
        "--variant", help="baseline (AgentFormer), goal, dr (driving force) or re (repulsive).", callback=check_variant
    ),
]


@app.command(
    "train-cvae",
    epilog="Examples:\n\n  fftool train-cvae --benchmarks zara1 --variant dr --config pipelines/quick.toml\n\n"
    "  torchrun --standalone --nproc-per-node 2 -m fftool train-cvae --variant dr --config pipelines/quick.toml"
    "   # data-parallel, 2 ranks (docs/scaling.md)",
)
@boundary
def train_cvae(
    benchmarks: BenchmarksOption = "zara1",
    variant: VariantOption = "baseline",
    device: DeviceOption = "auto",
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    force: ForceOption = False,
) -> None:
    """Train the AgentFormer CVAE with a ForceFormer input variant (batched, resumable, best by val minADE)."""
    from fftool.learning.distributed import leader
    from fftool.reporting.summaries import training_table
    from fftool.ui import out_console

    for benchmark in benchmarks.split(","):
        built = run_stages(["cvae"], config, set_, root, force, device, benchmark, {"cvae.variant": variant})
        if leader():  # under torchrun, rank 0 alone prints
            out_console.print(training_table(built["cvae"], f"CVAE {variant} ({benchmark})"))


@app.command(
    "train-dlow",
    epilog="Example: fftool train-dlow --benchmarks zara1 --variant dr --config pipelines/quick.toml",
)
@boundary
def train_dlow(
    benchmarks: BenchmarksOption = "zara1",
    variant: VariantOption = "baseline",
    device: DeviceOption = "auto",
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    force: ForceOption = False,
) -> None:
    """Train AgentFormer's DLow sampler over a trained CVAE (frozen): K codes per agent, best by val minADE.

    Evaluations of the variants in dlow.variants then draw their K futures from its codes (docs/cvae.md).
    """
    from fftool.reporting.summaries import training_table
    from fftool.ui import out_console

    for benchmark in benchmarks.split(","):
        built = run_stages(["dlow"], config, set_, root, force, device, benchmark, {"cvae.variant": variant})
        out_console.print(training_table(built["dlow"], f"DLow over CVAE {variant} ({benchmark})"))


@app.command(
    epilog="Examples:\n\n  fftool evaluate --benchmarks zara1 --variant dr --protocol paper -c pipelines/quick.toml\n\n"
    "  fftool evaluate --benchmarks all --variant cv      # the constant-velocity reference"
)
@boundary
def evaluate(
    benchmarks: BenchmarksOption = "zara1",
    variant: Annotated[
        str,
        typer.Option(
            "--variant",
            help="The trained CVAE of this variant (baseline, goal, dr, re), or cv, the constant-velocity reference.",
            callback=check_predictor,
        ),
    ] = "baseline",
    protocol: ProtocolOption = None,
    device: DeviceOption = "auto",
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    force: ForceOption = False,
) -> None:
    """Sample K futures per test agent-window; minADE/minFDE and collisions; predictions saved as Parquet."""
    from fftool.config import load_config, predictor_config
    from fftool.reporting.summaries import evaluation_table
    from fftool.ui import out_console

    cfg = predictor_config(load_config(config, set_, {"evaluate.protocol": protocol} if protocol else None), variant)
    built = [
        build_stages(cfg, ["evaluate"], root, force, device, benchmark)["evaluate"]
        for benchmark in benchmarks.split(",")
    ]
    out_console.print(evaluation_table(built))
