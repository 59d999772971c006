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
