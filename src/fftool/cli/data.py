"""`fftool fetch-data`: the raw ETH/UCY files, checked against pinned hashes."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from fftool.cli.app import (
    app,
    boundary,
)


@app.command("fetch-data", epilog="Example: fftool fetch-data --dest data/eth_ucy/raw")
@boundary
def fetch_data(
    dest: Annotated[
        Path, typer.Option("--dest", file_okay=False, help="Where to place all_data/, train/, val/.")
    ] = Path("data/eth_ucy/raw"),
    base_url: Annotated[
        str | None, typer.Option("--base-url", help="Mirror URL of the raw root (default: pinned public source).")
    ] = None,
) -> None:
    """Download the raw ETH/UCY files, check their pinned sha256, and place them where ingest expects."""
    from fftool.dataset.fetch import DEFAULT_BASE_URL, fetch_raw, registry
    from fftool.ui import log, progress

    with progress() as bar:
        task = bar.add_task("fetch raw files", total=len(registry()))
        status = fetch_raw(dest, base_url or DEFAULT_BASE_URL, on_file=lambda rel, _: bar.advance(task))
    downloaded = sum(1 for s in status.values() if s == "downloaded")
    log(f"{downloaded} downloaded, {len(status) - downloaded} already present and verified, in {dest}")
    log(f"next: fftool ingest --raw {dest}")


@app.command(
    "simulate-crowd",
    epilog="Example: fftool simulate-crowd crowd --agents 40 --seconds 120 --seed 0   # then: fftool ingest "
    "--dataset crowd/dataset.toml",
)
@boundary
def simulate_crowd(
    out_dir: Annotated[Path, typer.Argument(file_okay=False, help="Folder for train/val/test.csv and dataset.toml.")],
    agents: Annotated[int, typer.Option("--agents", min=1, help="Pedestrians over the whole recording.")] = 300,
    seconds: Annotated[float, typer.Option("--seconds", min=1.0, help="Length of the recording in seconds.")] = 600.0,
    seed: Annotated[int, typer.Option("--seed", min=0, help="Random seed: the same seed gives the same files.")] = 0,
    name: Annotated[str, typer.Option("--name", help="The dataset's benchmark name (--benchmarks NAME).")] = "crowd",
) -> None:
    """Simulate a corridor crowd with fftool's social forces and write it as a dataset (CSV files + dataset.toml)."""
    from fftool.dataset.custom import write_dataset
    from fftool.science.crowd import simulate_crowd as simulate
    from fftool.ui import log

    crowd = simulate(agents, seconds, seed)
    toml = write_dataset(out_dir, name, crowd.time_s, crowd.agent, crowd.xy, time_step_s=0.4)
    log(f"{len(crowd.time_s)} positions of {len(set(crowd.agent.tolist()))} pedestrians in {out_dir}")
    log(f"next: fftool ingest --dataset {toml}")
