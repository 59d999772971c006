"""`fftool models list / install / pack / rekey`: the trained models shipped in the repository."""

from __future__ import annotations

from typing import Annotated

import typer

from fftool.cli.app import RootOption, app, boundary, check_benchmarks, open_store
from fftool.dataset.scenes import BENCHMARKS

models_app = typer.Typer(
    help="The trained models shipped in models/<profile>/ (the model zoo).\n\nExample: fftool models list",
    no_args_is_help=True,
)
app.add_typer(models_app, name="models")

ProfileOption = Annotated[str, typer.Option("--profile", help="The profile the models were trained with.")]
ZooBenchmarks = Annotated[
    str,
    typer.Option("--benchmarks", help="Comma-separated benchmarks, or all.", callback=check_benchmarks),
]


@models_app.command(
    "list",
    epilog="Example: fftool models list   # then: fftool predict tracks.csv --model cpu/zara1/dr",
)
@boundary
def models_list(
    profile: Annotated[str | None, typer.Option("--profile", help="Only this profile's models.")] = None,
) -> None:
    """Every shipped model: its name, benchmark, variant, validation numbers, size, and whether it is current
    (the code still computes its fingerprint) or orphaned."""
    from fftool import zoo
    from fftool.reporting.summaries import zoo_table
    from fftool.ui import out_console

    names = [profile] if profile else zoo.profiles()
    models = [model for name in names for model in zoo.shipped(name)]
    for model in models:  # every file against its manifest: a damaged model is an error here too
        zoo.check(model, zoo.store(model.profile))
    out_console.print(zoo_table(models, set(zoo.orphans(models))))


@models_app.command(
    "install",
    epilog="Examples:\n\n  fftool models install                      # every cpu model, into ./artifacts\n\n"
    "  fftool models install --benchmarks zara1   # then: fftool reproduce pipelines/cpu.toml --benchmarks zara1",
)
@boundary
def models_install(
    profile: ProfileOption = "cpu",
    benchmarks: ZooBenchmarks = ",".join(BENCHMARKS),
    root: RootOption = None,
) -> None:
    """Place the shipped models into the artifact store under the fingerprints this code computes, every
    file checked against its manifest, so `fftool reproduce pipelines/<profile>.toml` trains nothing."""
    from fftool import zoo
    from fftool.ui import log

    models = zoo.shipped(profile, benchmarks.split(","))
    if not models:
        log(f"no shipped {profile} models for {benchmarks}")
        return
    store = open_store(root)
    done = zoo.install(store, models)
    installed = sum(status == "installed" for _, status in done)
    log(f"{installed} model(s) installed, {len(done) - installed} already in {store.root}")
    log(f"next: fftool reproduce pipelines/{profile}.toml --benchmarks {benchmarks}")


@models_app.command(
    "pack",
    epilog="Example: fftool reproduce pipelines/cpu.toml --benchmarks zara1 && fftool models pack --benchmarks zara1",
)
@boundary
def models_pack(
    benchmarks: Annotated[str, typer.Option("--benchmarks", callback=check_benchmarks, help="Benchmarks to pack.")],
    profile: ProfileOption = "cpu",
    root: RootOption = None,
) -> None:
    """Copy a profile's trained models (goal U-Net, CVAEs, DLow samplers) of the benchmarks given from the
    artifact store into models/<profile>/, replacing the shipped models of the same names."""
    from fftool import zoo
    from fftool.ui import log

    packed = zoo.pack(open_store(root), profile, benchmarks.split(","))
    log(f"packed {len(packed)} model(s) into models/{profile}: {', '.join(packed)}")


@models_app.command(
    "validate",
    epilog="Example: fftool sample-goals --benchmarks zara1 -c pipelines/cpu.toml && "
    "fftool models validate --benchmarks zara1",
)
@boundary
def models_validate(
    benchmarks: Annotated[str, typer.Option("--benchmarks", callback=check_benchmarks, help="Benchmarks to score.")],
    profile: ProfileOption = "cpu",
    root: RootOption = None,
) -> None:
    """Score the shipped goal variants (and their DLow samplers) under the fair protocol on their validation
    windows, sample k decoding the shipped goal U-Net's goal k, and record it for `fftool models list`. Reads
    the windows, forces and goals artifacts of the profile from the artifact store."""
    from fftool import zoo
    from fftool.ui import log

    scored = zoo.validate(open_store(root), profile, benchmarks.split(","))
    log(f"scored {len(scored)} model(s) under the fair protocol{': ' + ', '.join(scored) if scored else ''}")


@models_app.command("rekey", epilog="Example: fftool models rekey --profile cpu")
@boundary
def models_rekey(profile: ProfileOption = "cpu") -> None:
    """Move orphaned shipped models to the fingerprints the code computes now, when only code versions or
    upstream fingerprints changed (a model trained with other parameters is refused: retrain it)."""
    from fftool import zoo
    from fftool.ui import log

    moved = zoo.rekey(profile)
    log(f"re-keyed {len(moved)} model(s){': ' + ', '.join(moved) if moved else ''}")
