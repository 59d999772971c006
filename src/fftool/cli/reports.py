"""Commands over many artifacts: `reproduce` (alias `ablate`), `plot` and `rescore`."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from fftool.cli.app import (
    BenchmarksOption,
    ConfigOption,
    DeviceOption,
    OptionalBenchmarks,
    OutOption,
    ProtocolOption,
    RootOption,
    SetOption,
    VariantsOption,
    app,
    boundary,
    build_stages,
    check_predictor,
    check_threshold,
    open_store,
    profile_file,
)

SeedsOption = Annotated[
    str | None,
    typer.Option(
        "--seeds",
        help="Comma-separated grid seeds (report.seeds): every cell is trained and evaluated once per seed "
        "(each sets the goal, goals, cvae, dlow and evaluate seeds; seed 0 reuses the default cells); tables show "
        "mean ±sd over seeds, results.csv every seed.",
        show_default=False,
    ),
]
JobsOption = Annotated[
    int,
    typer.Option(
        "--jobs",
        "-j",
        min=1,
        help="Stage builds to run at once, each in its own worker process, in dependency order "
        "(default 1: one after another in this process). Artifacts and tables are the same as with one job.",
    ),
]
ThreadsOption = Annotated[
    int | None,
    typer.Option(
        "--threads",
        min=1,
        help="Torch threads per build. Default: the CPU cores shared out among --jobs (jobs × threads ≤ cores); "
        "with one job, torch's own choice (one per core, or OMP_NUM_THREADS).",
        show_default=False,
    ),
]
SchedulerOption = Annotated[
    str | None,
    typer.Option(
        "--scheduler",
        metavar="ADDRESS",
        help="A Dask scheduler (tcp://host:8786) whose workers run the builds (pip install 'fftool[cluster]'); "
        "the artifact root must be on a filesystem every worker sees (docs/scaling.md).",
        show_default=False,
    ),
]
PipelineArgument = Annotated[
    Path | None,
    typer.Argument(
        metavar="PIPELINE",
        dir_okay=False,
        callback=profile_file,
        help="A profile's TOML file (pipelines/cpu.toml) or a shipped profile's name (cpu), or -c. Default: the "
        "built-in defaults (the paper's configuration).",
        show_default=False,
    ),
]


def reproduce(
    pipeline_file: PipelineArgument = None,
    benchmarks: OptionalBenchmarks = None,
    variants: VariantsOption = None,
    protocol: ProtocolOption = None,
    device: DeviceOption = "auto",
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    out: OutOption = None,
    seeds: SeedsOption = None,
    jobs: JobsOption = 1,
    threads: ThreadsOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """The whole DAG from raw files to Tables II-VI (md, csv, tex) and figures; built stages are reused.

    Trains and evaluates whatever is missing for the baseline, the chosen variants and constant velocity, then
    scores every evaluation from its saved predictions: minADE, minFDE, NC, COL and Col-II, each with a
    bootstrap interval over test windows, and each variant's paired difference from the baseline.
    """
    from fftool import pipeline
    from fftool.config import load_config
    from fftool.errors import UsageError
    from fftool.reporting import ablation
    from fftool.reporting.summaries import report_tables, run_summary
    from fftool.ui import log, out_console

    if pipeline_file and config and pipeline_file.resolve() != config.resolve():
        raise UsageError(f"two pipelines given ({pipeline_file} and -c {config}); give one")
    chosen = pipeline_file or config
    values = ({"evaluate.protocol": protocol} if protocol else {}) | ({"report.seeds": _seeds(seeds)} if seeds else {})
    cfg = load_config(chosen, set_, values)
    store = open_store(root)
    profile = chosen.stem if chosen else "defaults"
    reports_dir = store.root / cfg.report.out_dir  # an absolute out_dir replaces the root
    out_dir = ablation.check_report_folder(out or reports_dir / profile, store.root, reports_dir)  # before any work
    report, results, minutes = ablation.reproduce(
        cfg,
        store,
        pipeline.Runtime(device=device),
        benchmarks.split(",") if benchmarks else list(cfg.report.benchmarks),
        [v for v in (variants.split(",") if variants is not None else cfg.report.variants) if v],
        out_dir,
        profile,
        command="fftool " + " ".join(sys.argv[1:]),
        workers=ablation.Workers(jobs, threads, scheduler),
    )
    for table in [*report_tables(report.parent), run_summary(results)]:
        out_console.print(table)
    log(f"report: {report} ({minutes:.1f} min)")


def _seeds(text: str) -> list[int]:
    """--seeds 0,1,2 -> [0, 1, 2]; anything but comma-separated non-negative integers is a usage error."""
    from fftool.errors import UsageError

    try:
        seeds = [int(part) for part in text.split(",")]
    except ValueError:
        raise UsageError(f"--seeds {text}: expected comma-separated integers, e.g. --seeds 0,1,2") from None
    if len(set(seeds)) != len(seeds) or min(seeds) < 0:
        raise UsageError(f"--seeds {text}: expected distinct non-negative integers, e.g. --seeds 0,1,2")
    return seeds


_REPRODUCE_EXAMPLES = (
    "Examples:\n\n  fftool reproduce pipelines/quick.toml --benchmarks zara1   # 10-14 min on a 2-core CPU\n\n"
    "  fftool reproduce pipelines/cpu.toml --benchmarks zara1 --jobs 2   # ~48 min on 2 cores\n\n"
    "  fftool reproduce pipelines/quick.toml --benchmarks zara1 --seeds 0,1,2   # 3 seeds, mean ±sd\n\n"
    "  fftool reproduce pipelines/quick.toml --benchmarks zara1 --jobs 2   # two builds at a time, 1 thread each\n\n"
    "  fftool reproduce pipelines/paper.toml --device cuda         # the full configuration, for a GPU\n\n"
    "  fftool ablate -c pipelines/quick.toml --variants dr --protocol paper --out paper/"
)
app.command(epilog=_REPRODUCE_EXAMPLES)(boundary(reproduce))
app.command(
    "ablate",
    epilog=_REPRODUCE_EXAMPLES,
    help="The same command as `fftool reproduce` (its older name): Tables II-VI from the whole DAG.",
)(boundary(reproduce))


@app.command(
    epilog="Examples:\n\n  fftool plot --benchmarks zara1 --variants baseline,dr,re -c pipelines/quick.toml\n\n"
    "  fftool plot --benchmarks zara1 --windows 12,25 --best --out figures/ -c pipelines/quick.toml\n\n"
    "  fftool plot --benchmarks zara1 --variants baseline,dr --animate gif --frames 40 -c pipelines/quick.toml"
)
@boundary
def plot(
    benchmarks: BenchmarksOption = "zara1",
    variants: Annotated[
        str, typer.Option("--variants", help="Predictors side by side: baseline, goal, dr, re, cv.")
    ] = "baseline,dr,re",
    windows: Annotated[
        str | None,
        typer.Option(
            "--windows",
            help="Comma-separated window ids. Default: where the predictors differ most, windows with 3 or more "
            "agents first, at least one window length apart.",
        ),
    ] = None,
    count: Annotated[int, typer.Option("--count", min=1, help="Windows to pick when --windows is not given.")] = 3,
    best: Annotated[bool, typer.Option("--best", help="Draw each agent's best-ADE sample only, not all K.")] = False,
    animate: Annotated[
        str | None,
        typer.Option(
            "--animate",
            help="Also animate a stretch of the test recording (around the first of --windows, else the first "
            "picked): gif, or mp4 where imageio-ffmpeg is installed; written as animation_<benchmark>.<format>.",
        ),
    ] = None,
    frames: Annotated[int, typer.Option("--frames", min=2, help="With --animate: windows (frames) to show.")] = 40,
    fps: Annotated[float, typer.Option("--fps", min=0.5, max=60, help="With --animate: frames per second.")] = 5.0,
    protocol: ProtocolOption = None,
    device: DeviceOption = "auto",
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    out: Annotated[Path, typer.Option("--out", file_okay=False, help="Folder for the PNG files.")] = Path("figures"),
) -> None:
    """Draw predictions over the scene image (like the paper's Fig. 3) and minFDE/collisions vs density.

    Reads the saved predictions of each predictor's evaluation (evaluated first if only the model exists).
    """
    from fftool.config import load_config, predictor_config
    from fftool.errors import UsageError
    from fftool.reporting import plots
    from fftool.ui import log

    if animate is not None:
        from fftool.reporting.animation import FORMATS
        from fftool.reporting.animation import check_out as check_animation

        if animate not in FORMATS:  # a format, never a path: the file is named inside --out
            raise UsageError(f"--animate {animate}: expected one of {', '.join(FORMATS)}")
        for benchmark in benchmarks.split(","):
            check_animation(out / f"animation_{benchmark}.{animate}")
    predictors = [check_predictor(v.strip()) for v in variants.split(",") if v.strip()]
    cfg = load_config(config, set_, {"evaluate.protocol": protocol} if protocol else None)
    names = benchmarks.split(",")
    if windows and len(names) > 1:
        raise UsageError("--windows names windows of one benchmark; give one in --benchmarks")
    for benchmark in names:
        built = [
            build_stages(predictor_config(cfg, predictor), ["evaluate"], root, False, device, benchmark)
            for predictor in predictors
        ]
        written = plots.figures(
            {benchmark: [plots.Evaluation.of(b["evaluate"]) for b in built]},
            built[0]["windows"],
            cfg.evaluate.part,
            Path(cfg.data.scenes_dir),
            out,
            density_file=f"density_{benchmark}.png",
            window_ids=[int(w) for w in windows.split(",")] if windows else None,
            count=count,
            best_only=best,
            resampling=plots.resampling_of(cfg.report, cfg.windows),
        )
        log(f"wrote {', '.join(map(str, written))}")
        if animate is not None:
            from fftool.reporting.animation import animate_test

            drawn = [plots.Evaluation.of(b["evaluate"]) for b, p in zip(built, predictors) if p != "cv"] or [
                plots.Evaluation.of(built[0]["evaluate"])
            ]
            movie = animate_test(
                drawn, built[0]["windows"], cfg.evaluate.part, Path(cfg.data.scenes_dir),
                out / f"animation_{benchmark}.{animate}", dt_s=cfg.ingest.dt_s,
                threshold_m=cfg.evaluate.collision_threshold_m, start=int(windows.split(",")[0]) if windows else None,
                frames=frames, fps=fps, best_only=best,
            )  # fmt: skip
            log(f"wrote {movie}")


@app.command(epilog="Example: fftool rescore evaluate/3f9c2a --threshold 0.2   # ids: fftool artifacts list")
@boundary
def rescore(
    artifact_id: Annotated[
        str,
        typer.Argument(
            metavar="ID",
            help="An evaluate artifact: evaluate/fingerprint-prefix (see `fftool artifacts list --kind evaluate`).",
        ),
    ],
    threshold: Annotated[
        float,
        typer.Option(
            "--threshold",
            help="Collision threshold γ in metres (evaluate.collision_threshold_m).",
            callback=check_threshold,
        ),
    ],
    root: RootOption = None,
) -> None:
    """Re-score an evaluation's saved predictions at another collision threshold, without sampling again.

    Also prints COL and Col-II, so evaluations built before those metrics existed gain them.
    """
    from fftool.reporting.rescoring import rescore_artifact
    from fftool.reporting.summaries import rescore_table
    from fftool.ui import out_console

    store = open_store(root)
    evaluation = store.resolve(artifact_id)
    out_console.print(rescore_table(evaluation, rescore_artifact(store, evaluation, threshold)))
