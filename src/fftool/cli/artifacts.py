"""`fftool artifacts list / show / verify`: look into the store and check it."""

from __future__ import annotations

from typing import Annotated

import typer

from fftool.cli.app import (
    RootOption,
    app,
    boundary,
    open_store,
)
from fftool.errors import FftoolError

artifacts_app = typer.Typer(
    help="Inspect and verify built artifacts.\n\nExample: fftool artifacts list",
    no_args_is_help=True,
)


app.add_typer(artifacts_app, name="artifacts")


@artifacts_app.command("list", epilog="Example: fftool artifacts list --kind windows")
@boundary
def artifacts_list(
    kind: Annotated[str | None, typer.Option("--kind", help="Only artifacts of this kind (stage name).")] = None,
    root: RootOption = None,
) -> None:
    """List every complete artifact: id, creation time, size and the artifacts it was built from."""
    from fftool.reporting.summaries import artifacts_table
    from fftool.ui import out_console

    out_console.print(artifacts_table(open_store(root).list(kind)))


@artifacts_app.command(
    "show",
    epilog="Example: fftool artifacts show windows   # the only one; else windows/<fingerprint prefix>",
)
@boundary
def artifacts_show(
    artifact_id: Annotated[str, typer.Argument(metavar="ID", help="kind/fingerprint-prefix, a prefix, or a kind.")],
    root: RootOption = None,
) -> None:
    """Print one artifact's manifest (kind, schema version, parameters, inputs, files, stats)."""
    from rich.json import JSON

    from fftool.ui import out_console

    artifact = open_store(root).resolve(artifact_id)
    out_console.print(f"[bold]{artifact.id}[/]  {artifact.path}")
    out_console.print(JSON(artifact.manifest.to_json()))


@artifacts_app.command(
    "verify",
    epilog="Examples:\n\n  fftool artifacts verify              # every artifact, and folders that cannot be read\n\n"
    "  fftool artifacts verify cvae/3f9c2a  # one artifact (ids: fftool artifacts list) and its inputs",
)
@boundary
def artifacts_verify(
    artifact_id: Annotated[
        str | None, typer.Argument(metavar="[ID]", help="One artifact and its inputs, recursively; default: all.")
    ] = None,
    root: RootOption = None,
) -> None:
    """Re-hash artifact files and report any that changed since they were built (exit 1 if any)."""
    from fftool.artifacts.store import Artifact
    from fftool.ui import out_console

    store = open_store(root)
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
