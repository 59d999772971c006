"""The Typer app, its one error boundary and the options the commands share.

Every command goes through `boundary`, the single place where errors become `Error: <message>` on
stderr with exit code 2 (usage: config, --out, parser errors) or 1 (data), never a traceback. Heavy
libraries (pandas, pyarrow, torch) are imported inside commands so `fftool --help` stays fast.
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

from fftool.dataset.scenes import BENCHMARKS
from fftool.errors import FftoolError, UsageError
from fftool.variants import FORCEFORMER_VARIANTS, PREDICTORS, VARIANTS

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


def _print_version(asked: bool) -> None:
    if asked:
        from fftool import __version__
        from fftool.zoo import models_version

        typer.echo(f"fftool {__version__}; models: {models_version()}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool,
        typer.Option(
            "--version",
            help="Print fftool's version and where its shipped models come from, and exit.",
            callback=_print_version,
            is_eager=True,
        ),
    ] = False,
) -> None:
    """ForceFormer pedestrian-trajectory prediction, reproducible: one command per pipeline stage.

    Example: fftool ingest --raw ../shared/data/eth_ucy/raw
    """


RootOption = Annotated[
    Path | None,
    typer.Option("--root", help="Artifact root. Default: $FFTOOL_ARTIFACTS or ./artifacts.", show_default=False),
]


def profile_file(value: Path | None) -> Path | None:
    """A pipeline TOML file, or the name of a profile the shipped models came with (`cpu`: pipelines/cpu.toml
    beside the models, in a checkout or the installed fftool-models wheel)."""
    if value is None or value.is_file():
        return value
    from fftool.zoo import pipelines_root

    shipped = pipelines_root() / f"{value}.toml"
    if value.suffix == "" and value.parent == Path() and shipped.is_file():
        return shipped
    names = ", ".join(sorted(p.stem for p in pipelines_root().glob("*.toml"))) or "none here"
    raise typer.BadParameter(f"{value}: no such file, nor a shipped profile's name ({names})")


ConfigOption = Annotated[
    Path | None,
    typer.Option(
        "--config",
        "-c",
        dir_okay=False,
        callback=profile_file,
        help="Pipeline TOML file (e.g. pipelines/quick.toml), or a shipped profile's name (quick, cpu).",
    ),
]


SetOption = Annotated[
    list[str] | None,
    typer.Option(
        "--set",
        help="Override a config value: section.key=value, or one variant's: "
        "per_variant.<variant>.<section>.key=value (repeatable).",
    ),
]


ForceOption = Annotated[bool, typer.Option("--force", help="Rebuild even if an artifact with this fingerprint exists.")]


def boundary(func: F) -> F:
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


def open_store(root: Path | None) -> Any:
    from fftool.artifacts.store import ArtifactStore, default_root

    return ArtifactStore(root or default_root())


def run_stages(
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
    return build_stages(cfg, targets, root, force, device, benchmark)


def build_stages(
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
        open_store(root),
        targets,
        force=targets if force else [],
        runtime=pipeline.Runtime(device=device),
        upstream=False,
        benchmark=benchmark,
    )


def check_device(value: str) -> str:
    from fftool.config import DEVICE_CHOICES

    if value not in DEVICE_CHOICES:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(DEVICE_CHOICES)}")
    return value


DeviceOption = Annotated[
    str,
    typer.Option("--device", help="Torch device: auto (CUDA when available), cpu or cuda.", callback=check_device),
]


def check_benchmarks(value: str) -> str:
    """ETH/UCY names, or all of them; any other well-formed name is a dataset's (data.dataset), which the
    engine checks once the configuration is read."""
    from fftool.dataset.custom import valid_name

    names = BENCHMARKS if value == "all" else tuple(v.strip() for v in value.split(","))
    unknown = [name for name in names if name not in BENCHMARKS and not valid_name(name)]
    if unknown:
        raise typer.BadParameter(
            f"unknown benchmark(s) {', '.join(unknown)}; choose from {', '.join(BENCHMARKS)} or all, "
            "or a dataset's name"
        )
    return ",".join(names)


BenchmarksOption = Annotated[
    str,
    typer.Option(
        "--benchmarks", help=f"Comma-separated benchmarks ({', '.join(BENCHMARKS)}), or all.", callback=check_benchmarks
    ),
]


def check_variant(value: str) -> str:
    if value not in VARIANTS:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(VARIANTS)}")
    return value


def check_predictor(value: str) -> str:
    if value not in PREDICTORS:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(PREDICTORS)}")
    return value


def check_protocol(value: str) -> str:
    from fftool.learning.protocols import PROTOCOLS

    if value not in PROTOCOLS:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(PROTOCOLS)}")
    return value


def check_variants(value: str) -> str:
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
        "Goal protocol of goal variants: fair (sample k decodes sampled goal k; reads no true future), paper (the "
        "paper's pick: the sampled goal nearest the true end point), oracle (true goal). Default: evaluate.protocol "
        "of the config (fair).",
        check_protocol,
    ),
]


VariantsOption = Annotated[
    str | None,
    _optional(
        "--variants",
        "Comma-separated ForceFormer variants besides the baseline (always included): "
        f"{', '.join(FORCEFORMER_VARIANTS)}. Default: report.variants of the config (all three).",
        check_variants,
    ),
]


OptionalBenchmarks = Annotated[
    str | None,
    _optional(
        "--benchmarks",
        "Comma-separated benchmarks, or all. Default: report.benchmarks of the config (all five).",
        check_benchmarks,
    ),
]


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


def check_threshold(value: float) -> float:
    if not 0 < value < float("inf"):  # also refuses nan
        raise typer.BadParameter(f"{value!r} is not a distance in metres above 0")
    return value
