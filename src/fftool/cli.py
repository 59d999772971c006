"""The `fftool` command line: one thin command per stage; the science lives in the stage modules.

Every command goes through `_boundary`, the single place where fftool errors become
`Error: <message>` on stderr with exit code 1 (usage errors exit 2, from Typer's parser). Heavy libraries (pandas,
pyarrow, torch) are imported inside commands so `fftool --help` stays fast.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypeVar

import typer
from typer.core import TyperGroup

from fftool.errors import FftoolError, UsageError
from fftool.published import FORCEFORMER_VARIANTS, PREDICTORS, VARIANTS
from fftool.scenes import BENCHMARKS

if TYPE_CHECKING:
    from fftool.config import PipelineConfig

F = TypeVar("F", bound=Callable[..., Any])


class _OneLineUsageErrors(TyperGroup):
    """Typer's parser errors (bad option values, unknown options) as one `Error:` line, exit 2.

    Typer draws them as a boxed panel that wraps long paths over several lines; fftool promises one
    line for every failure, whatever raised it.
    """

    def main(self, *args: Any, standalone_mode: bool = True, **kwargs: Any) -> Any:
        if not standalone_mode:
            return super().main(*args, standalone_mode=False, **kwargs)
        try:
            code = super().main(*args, standalone_mode=False, **kwargs)
        except typer.TyperException as exc:  # click's UsageError, BadParameter, NoSuchOption, …
            if type(exc).__name__ == "NoArgsIsHelpError":
                exc.show()  # type: ignore[attr-defined]
                sys.exit(0)
            context = getattr(exc, "ctx", None)
            hint = f" (see `{context.command_path} --help`)" if context is not None else ""
            _print_error(" ".join(exc.format_message().split()) + hint)
            code = exc.exit_code
        except typer.Exit as exc:
            code = exc.exit_code
        except typer.Abort:
            _print_error("aborted")
            code = 1
        sys.exit(code if isinstance(code, int) else 0)


app = typer.Typer(
    cls=_OneLineUsageErrors,
    name="fftool",
    help="ForceFormer pedestrian-trajectory prediction, reproducible: one command per pipeline stage.\n\n"
    "Example: fftool ingest --raw ../shared/data/eth_ucy/raw",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
artifacts_app = typer.Typer(
    help="Inspect and verify built artifacts.\n\nExample: fftool artifacts list",
    no_args_is_help=True,
)
app.add_typer(artifacts_app, name="artifacts")

RootOption = Annotated[
    Path | None,
    typer.Option("--root", help="Artifact root. Default: $FFTOOL_ARTIFACTS or ./artifacts.", show_default=False),
]
ConfigOption = Annotated[
    Path | None,
    typer.Option("--config", "-c", exists=True, dir_okay=False, help="Pipeline TOML file (e.g. pipelines/quick.toml)."),
]
SetOption = Annotated[
    list[str] | None,
    typer.Option("--set", help="Override a config value: section.key=value (repeatable)."),
]
ForceOption = Annotated[bool, typer.Option("--force", help="Rebuild even if an artifact with this fingerprint exists.")]


def _boundary(func: F) -> F:
    """Turn every error into one `Error: …` line: exit 2 for usage (config, --out), 1 otherwise, no traceback."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        code = 1
        try:
            return func(*args, **kwargs)
        except UsageError as exc:  # a bad --set, pipeline file or --out folder
            message, code = str(exc), 2
        except FftoolError as exc:
            message = str(exc)
        except OSError as exc:
            message = f"{exc.filename or ''}: {exc.strerror or exc}".lstrip(": ")
        except KeyboardInterrupt:
            message = "interrupted; no partial artifact was kept"
        except (typer.Exit, typer.BadParameter):
            raise
        except Exception as exc:  # the last line of defence: a user never sees a traceback
            if os.environ.get("FFTOOL_DEBUG"):
                raise
            message = (
                f"unexpected {type(exc).__name__}: {exc} (input fftool does not check yet, or a bug; "
                "FFTOOL_DEBUG=1 shows the traceback)"
            )
        _fail(message, code)

    return wrapper  # type: ignore[return-value]


def _fail(message: str, code: int) -> None:
    _print_error(message)
    raise typer.Exit(code)


def _print_error(message: str) -> None:
    from fftool.ui import err_console

    err_console.print(f"Error: {message}", markup=False, soft_wrap=True, highlight=False)


def _store(root: Path | None) -> Any:
    from fftool.store import ArtifactStore, default_root

    return ArtifactStore(root or default_root())


def _run_stages(
    targets: list[str],
    config: Path | None,
    overrides: list[str] | None,
    root: Path | None,
    force: bool,
    device: str = "auto",
    benchmark: str | None = None,
    values: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """What every stage command does: resolve the config, build its own stage(s), require the rest.

    `values` are the command's typed options (`{"section.key": value}`), applied after `--set`.
    """
    from fftool.config import load_config

    cfg = load_config(config, list(overrides or []), values)
    return _build_stages(cfg, targets, root, force, device, benchmark)


def _build_stages(
    cfg: PipelineConfig,
    targets: list[str],
    root: Path | None,
    force: bool,
    device: str = "auto",
    benchmark: str | None = None,
) -> dict[str, Any]:
    """Build `targets` of a resolved configuration; the stages before them must exist."""
    from fftool import pipeline

    return pipeline.run(
        cfg,
        _store(root),
        targets,
        force=targets if force else [],
        runtime=pipeline.Runtime(device=device),
        upstream=False,
        benchmark=benchmark,
    )


def _check_device(value: str) -> str:
    if value not in ("auto", "cpu", "cuda"):
        raise typer.BadParameter(f"{value!r} is not one of auto, cpu, cuda")
    return value


DeviceOption = Annotated[
    str,
    typer.Option("--device", help="Torch device: auto (CUDA when available), cpu or cuda.", callback=_check_device),
]


@app.command(epilog="Example: fftool ingest --raw ../shared/data/eth_ucy/raw --root artifacts")
@_boundary
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
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    force: ForceOption = False,
) -> None:
    """Validate the raw ETH/UCY files and build the tracks and windows artifacts, with a summary table."""
    from fftool.reports import windows_summary_table
    from fftool.ui import out_console

    values = {"data.raw_dir": str(raw)} if raw else {}
    built = _run_stages(["tracks", "windows"], config, set_, root, force, values=values)
    out_console.print(windows_summary_table(built["windows"]))


@app.command(
    epilog="Examples: fftool forces    |    fftool forces --explain zara1 3900 --out docs/img/forces_zara1.png"
)
@_boundary
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
    from fftool.reports import forces_summary_table
    from fftool.ui import log, out_console

    built = _run_stages(["forces"], config, set_, root, force, device)
    out_console.print(forces_summary_table(built["forces"]))
    if explain:
        from fftool.explain import explain_window

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
@_boundary
def maps(
    config: ConfigOption = None, set_: SetOption = None, root: RootOption = None, force: ForceOption = False
) -> None:
    """Warp each scene image onto a metric ground grid and derive semantic channels (with check PNGs)."""
    from fftool.reports import maps_table
    from fftool.ui import out_console

    out_console.print(maps_table(_run_stages(["maps"], config, set_, root, force)["maps"]))


def _check_benchmark(value: str) -> str:
    if value not in BENCHMARKS:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(BENCHMARKS)}")
    return value


def _check_benchmarks(value: str) -> str:
    names = BENCHMARKS if value == "all" else tuple(v.strip() for v in value.split(","))
    unknown = [name for name in names if name not in BENCHMARKS]
    if unknown:
        raise typer.BadParameter(
            f"unknown benchmark(s) {', '.join(unknown)}; choose from {', '.join(BENCHMARKS)} or all"
        )
    return ",".join(names)


BenchmarkOption = Annotated[
    str,
    typer.Option(
        "--benchmark", "-b", help=f"Leave-one-out benchmark: {', '.join(BENCHMARKS)}.", callback=_check_benchmark
    ),
]
BenchmarksOption = Annotated[
    str, typer.Option("--benchmarks", help="Comma-separated benchmarks, or all.", callback=_check_benchmarks)
]


@app.command("train-goal", epilog="Example: fftool train-goal --benchmark zara1 --config pipelines/quick.toml")
@_boundary
def train_goal(
    benchmark: BenchmarkOption = "zara1",
    device: DeviceOption = "auto",
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    force: ForceOption = False,
) -> None:
    """Train the U-Net goal estimator on a benchmark's train part (resumable; best epoch by val goal-FDE)."""
    from fftool.reports import training_table
    from fftool.ui import out_console

    built = _run_stages(["goal"], config, set_, root, force, device, benchmark)
    out_console.print(training_table(built["goal"], "goal U-Net"))


@app.command(
    "sample-goals", epilog="Example: fftool sample-goals --benchmarks zara1,zara2 --config pipelines/quick.toml"
)
@_boundary
def sample_goals(
    benchmarks: BenchmarksOption = "all",
    device: DeviceOption = "auto",
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    force: ForceOption = False,
) -> None:
    """Sample K goals per agent-window with trained goal U-Nets; table of goal-FDE@K vs anchors and CV."""
    from fftool.reports import goal_fde_table
    from fftool.ui import out_console

    artifacts = {
        benchmark: _run_stages(["goals"], config, set_, root, force, device, benchmark)["goals"]
        for benchmark in benchmarks.split(",")
    }
    out_console.print(goal_fde_table(artifacts))


def _check_variant(value: str) -> str:
    if value not in VARIANTS:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(VARIANTS)}")
    return value


@app.command(
    "train-cvae", epilog="Example: fftool train-cvae --benchmark zara1 --variant dr --config pipelines/quick.toml"
)
@_boundary
def train_cvae(
    benchmark: BenchmarkOption = "zara1",
    variant: Annotated[
        str,
        typer.Option(
            "--variant",
            help="baseline (AgentFormer), goal, dr (driving force) or re (repulsive).",
            callback=_check_variant,
        ),
    ] = "baseline",
    device: DeviceOption = "auto",
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    force: ForceOption = False,
) -> None:
    """Train the AgentFormer CVAE with a ForceFormer input variant (batched, resumable, best by val minADE)."""
    from fftool.reports import training_table
    from fftool.ui import out_console

    built = _run_stages(["cvae"], config, set_, root, force, device, benchmark, {"cvae.variant": variant})
    out_console.print(training_table(built["cvae"], f"CVAE {variant}"))


def _check_predictor(value: str) -> str:
    if value not in PREDICTORS:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(PREDICTORS)}")
    return value


def _check_protocol(value: str) -> str:
    from fftool.protocols import PROTOCOLS

    if value not in PROTOCOLS:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(PROTOCOLS)}")
    return value


def _check_variants(value: str) -> str:
    names = tuple(v.strip() for v in value.split(",") if v.strip())
    unknown = [name for name in names if name not in VARIANTS]
    if unknown:
        raise typer.BadParameter(
            f"unknown variant(s) {', '.join(unknown)}; choose from {', '.join(FORCEFORMER_VARIANTS)}"
        )
    return ",".join(name for name in names if name != "baseline")


def _optional(flag: str, help_text: str, check: Callable[[str], str]) -> Any:
    """An option whose absence means 'take it from the config'."""
    return typer.Option(flag, help=help_text, callback=lambda v: v if v is None else check(v), show_default=False)


ProtocolOption = Annotated[
    str | None,
    _optional(
        "--protocol",
        "Goal protocol of goal variants: paper (sampled goal closest to the truth), fair (sample k uses goal k), "
        "oracle (true goal). Default: evaluate.protocol of the config (paper).",
        _check_protocol,
    ),
]
VariantsOption = Annotated[
    str | None,
    _optional(
        "--variants",
        "Comma-separated ForceFormer variants besides the baseline (always included): "
        f"{', '.join(FORCEFORMER_VARIANTS)}. Default: report.variants of the config (all three).",
        _check_variants,
    ),
]
OptionalBenchmarks = Annotated[
    str | None,
    _optional(
        "--benchmarks",
        "Comma-separated benchmarks, or all. Default: report.benchmarks of the config (all five).",
        _check_benchmarks,
    ),
]


@app.command(
    epilog="Examples:\n\n  fftool evaluate --benchmarks zara1 --variant dr --protocol paper -c pipelines/quick.toml\n\n"
    "  fftool evaluate --benchmarks all --variant cv      # the constant-velocity reference"
)
@_boundary
def evaluate(
    benchmarks: BenchmarksOption = "zara1",
    variant: Annotated[
        str,
        typer.Option(
            "--variant",
            help="The trained CVAE of this variant (baseline, goal, dr, re), or cv, the constant-velocity reference.",
            callback=_check_predictor,
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
    from fftool.reports import evaluation_table
    from fftool.ui import out_console

    cfg = predictor_config(load_config(config, set_, {"evaluate.protocol": protocol} if protocol else None), variant)
    built = [
        _build_stages(cfg, ["evaluate"], root, force, device, benchmark)["evaluate"]
        for benchmark in benchmarks.split(",")
    ]
    out_console.print(evaluation_table(built))


def _ablation(
    config: Path | None,
    set_: list[str] | None,
    benchmarks: str | None,
    variants: str | None,
    protocol: str | None,
    device: str,
    root: Path | None,
    out: Path | None,
    command: str,
) -> None:
    """ablate and reproduce: build every evaluation through the DAG, then write and print the tables."""
    import time

    from fftool import ablation, pipeline
    from fftool.config import load_config
    from fftool.reports import report_tables, run_summary
    from fftool.ui import log, out_console

    started = time.perf_counter()
    cfg = load_config(config, set_, {"evaluate.protocol": protocol} if protocol else None)
    chosen_benchmarks = benchmarks.split(",") if benchmarks else list(cfg.report.benchmarks)
    chosen_variants = variants.split(",") if variants is not None else list(cfg.report.variants)
    store = _store(root)
    profile = config.stem if config else "defaults"
    reports_dir = store.root / cfg.report.out_dir  # an absolute out_dir replaces the root
    out_dir = ablation.check_report_folder(out or reports_dir / profile, store.root, reports_dir)  # before any work
    results = ablation.run(
        cfg,
        store,
        pipeline.Runtime(device=device),
        chosen_benchmarks,
        [v for v in chosen_variants if v],
        on_cell=lambda b, p: log(f"[bold]{b} / {p}[/]"),
    )
    draw = lambda folder: ablation.figures(cfg, store, results, folder)  # noqa: E731
    report = ablation.write_report(cfg, results, out_dir, profile, command, time.perf_counter() - started, draw)
    for table in [*report_tables(report.parent), run_summary(results)]:
        out_console.print(table)
    log(f"report: {report} ({(time.perf_counter() - started) / 60:.1f} min)")


OutOption = Annotated[
    Path | None,
    typer.Option(
        "--out",
        file_okay=False,
        help="Report folder: new, empty, or a previous fftool report (it is replaced). Default: "
        "<root>/reports/<profile>.",
        show_default=False,
    ),
]


@app.command(epilog="Example: fftool ablate --variants goal,dr,re --benchmarks zara1 -c pipelines/quick.toml")
@_boundary
def ablate(
    variants: VariantsOption = None,
    benchmarks: OptionalBenchmarks = None,
    protocol: ProtocolOption = None,
    device: DeviceOption = "auto",
    config: ConfigOption = None,
    set_: SetOption = None,
    root: RootOption = None,
    out: OutOption = None,
) -> None:
    """Train what is missing, evaluate baseline + variants (+ cv), write Tables II-IV as md, csv and tex."""
    import sys

    _ablation(config, set_, benchmarks, variants, protocol, device, root, out, "fftool " + " ".join(sys.argv[1:]))


@app.command(
    epilog="Examples:\n\n  fftool reproduce pipelines/quick.toml --benchmarks zara1   # < 15 min on a 2-core CPU\n\n"
    "  fftool reproduce pipelines/cpu.toml --benchmarks zara1     # longer CPU training, about 1.5-2 h\n\n"
    "  fftool reproduce pipelines/paper.toml --device cuda         # the full configuration, for a GPU"
)
@_boundary
def reproduce(
    pipeline_file: Annotated[
        Path, typer.Argument(metavar="PIPELINE", exists=True, dir_okay=False, help="A profile in pipelines/.")
    ],
    benchmarks: OptionalBenchmarks = None,
    variants: VariantsOption = None,
    protocol: ProtocolOption = None,
    device: DeviceOption = "auto",
    set_: SetOption = None,
    root: RootOption = None,
    out: OutOption = None,
) -> None:
    """The whole DAG from raw files to the paper's tables; stages already built are reused."""
    import sys

    _ablation(
        pipeline_file, set_, benchmarks, variants, protocol, device, root, out, "fftool " + " ".join(sys.argv[1:])
    )


@app.command(
    epilog="Examples:\n\n  fftool plot --benchmark zara1 --variants baseline,dr,re -c pipelines/quick.toml\n\n"
    "  fftool plot --benchmark eth --windows 12,40 --best --out figures/"
)
@_boundary
def plot(
    benchmark: BenchmarkOption = "zara1",
    variants: Annotated[
        str, typer.Option("--variants", help="Predictors side by side: baseline, goal, dr, re, cv.")
    ] = "baseline,dr,re",
    windows: Annotated[
        str | None,
        typer.Option("--windows", help="Comma-separated window ids. Default: where the predictors differ most."),
    ] = None,
    count: Annotated[int, typer.Option("--count", min=1, help="Windows to pick when --windows is not given.")] = 3,
    best: Annotated[bool, typer.Option("--best", help="Draw each agent's best-ADE sample only, not all K.")] = False,
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
    from fftool import plots
    from fftool.config import load_config, predictor_config
    from fftool.ui import log

    predictors = [_check_predictor(v.strip()) for v in variants.split(",") if v.strip()]
    cfg = load_config(config, set_, {"evaluate.protocol": protocol} if protocol else None)
    built = [
        _build_stages(predictor_config(cfg, predictor), ["evaluate"], root, False, device, benchmark)
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
    )
    log(f"wrote {', '.join(map(str, written))}")


def _check_threshold(value: float) -> float:
    if not 0 < value < float("inf"):  # also refuses nan
        raise typer.BadParameter(f"{value!r} is not a distance in metres above 0")
    return value


@app.command(epilog="Example: fftool rescore evaluate/3f9c2a --threshold 0.2")
@_boundary
def rescore(
    artifact_id: Annotated[
        str,
        typer.Argument(
            metavar="ID", help="An evaluate artifact: evaluate/fingerprint-prefix, or evaluate (the newest)."
        ),
    ],
    threshold: Annotated[
        float,
        typer.Option(
            "--threshold",
            help="Collision threshold γ in metres (evaluate.collision_threshold_m).",
            callback=_check_threshold,
        ),
    ],
    root: RootOption = None,
) -> None:
    """Re-score an evaluation's saved predictions at another collision threshold, without sampling again."""
    from fftool.evaluate import rescore_artifact
    from fftool.reports import rescore_table
    from fftool.ui import out_console

    store = _store(root)
    evaluation = store.resolve(artifact_id)
    out_console.print(rescore_table(evaluation, rescore_artifact(store, evaluation, threshold)))


@app.command("fetch-data", epilog="Example: fftool fetch-data --dest data/eth_ucy/raw")
@_boundary
def fetch_data(
    dest: Annotated[
        Path, typer.Option("--dest", file_okay=False, help="Where to place all_data/, train/, val/.")
    ] = Path("data/eth_ucy/raw"),
    base_url: Annotated[
        str | None, typer.Option("--base-url", help="Mirror URL of the raw root (default: pinned public source).")
    ] = None,
) -> None:
    """Download the raw ETH/UCY files, check their pinned sha256, and place them where ingest expects."""
    from fftool.fetch import DEFAULT_BASE_URL, fetch_raw, registry
    from fftool.ui import log, progress

    with progress() as bar:
        task = bar.add_task("fetch raw files", total=len(registry()))
        status = fetch_raw(dest, base_url or DEFAULT_BASE_URL, on_file=lambda rel, _: bar.advance(task))
    downloaded = sum(1 for s in status.values() if s == "downloaded")
    log(f"{downloaded} downloaded, {len(status) - downloaded} already present and verified, in {dest}")
    log(f"next: fftool ingest --raw {dest}")


@artifacts_app.command("list", epilog="Example: fftool artifacts list --kind windows")
@_boundary
def artifacts_list(
    kind: Annotated[str | None, typer.Option("--kind", help="Only artifacts of this kind (stage name).")] = None,
    root: RootOption = None,
) -> None:
    """List every complete artifact: id, creation time, size and the artifacts it was built from."""
    from fftool.reports import artifacts_table
    from fftool.ui import out_console

    out_console.print(artifacts_table(_store(root).list(kind)))


@artifacts_app.command("show", epilog="Example: fftool artifacts show windows/3f9c2a")
@_boundary
def artifacts_show(
    artifact_id: Annotated[str, typer.Argument(metavar="ID", help="kind/fingerprint-prefix, a prefix, or a kind.")],
    root: RootOption = None,
) -> None:
    """Print one artifact's manifest (kind, schema version, parameters, inputs, files, stats)."""
    from rich.json import JSON

    from fftool.ui import out_console

    artifact = _store(root).resolve(artifact_id)
    out_console.print(f"[bold]{artifact.id}[/]  {artifact.path}")
    out_console.print(JSON(artifact.manifest.to_json()))


@artifacts_app.command(
    "verify",
    epilog="Examples:\n\n  fftool artifacts verify              # every artifact, and folders that cannot be read\n\n"
    "  fftool artifacts verify cvae/3f9c2a  # one artifact and every artifact it was built from",
)
@_boundary
def artifacts_verify(
    artifact_id: Annotated[
        str | None, typer.Argument(metavar="[ID]", help="One artifact and its inputs, recursively; default: all.")
    ] = None,
    root: RootOption = None,
) -> None:
    """Re-hash artifact files and report any that changed since they were built (exit 1 if any)."""
    from fftool.store import Artifact
    from fftool.ui import out_console

    store = _store(root)
    targets = store.chain(store.resolve(artifact_id)) if artifact_id else [*store.list(), *store.damaged()]
    bad = 0
    for target in targets:
        if isinstance(target, Artifact):
            problems = store.verify(target)
            out_console.print(f"{'[red]CHANGED[/]' if problems else '[green]ok[/]'}  {target.id}")
        else:  # a folder that cannot be read (IntegrityError) or an input no longer in the store (str)
            problems = [str(target)]
            out_console.print("[red]DAMAGED[/]" if isinstance(target, FftoolError) else "[red]MISSING[/]")
        for problem in problems:
            out_console.print(f"      {problem}", markup=False, soft_wrap=True)
        bad += bool(problems)
    if bad:
        raise FftoolError(f"{bad} of {len(targets)} artifact(s) changed, damaged or missing")
    out_console.print(f"{len(targets)} artifact(s) verified")
