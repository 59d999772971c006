"""Download the raw ETH/UCY files from their public source and check their pinned sha256.

Run: `fftool fetch-data --dest data/eth_ucy/raw`. Every file is downloaded into a temporary folder
next to the destination and checked; only when all 24 files verify are they moved into place, so a
failed or corrupted download keeps nothing.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Final

from fftool.artifacts.hashing import sha256_file
from fftool.errors import FetchError, UsageError

# The Social-GAN text files as redistributed by Trajectron++ (pinned commit, so the bytes never move).
DEFAULT_BASE_URL: Final = (
    "https://raw.githubusercontent.com/StanfordASL/Trajectron-plus-plus/"
    "40dec06e9cfef9e0d5f5ec69da2c4058a556bba9/experiments/pedestrians/raw/raw/"
)


def registry() -> dict[str, str]:
    """Relative path -> sha256 of every raw file (package data `registry/eth_ucy_raw.txt`)."""
    text = resources.files("fftool.dataset").joinpath("registry/eth_ucy_raw.txt").read_text()
    pairs = (line.split() for line in text.splitlines() if line.strip() and not line.startswith("#"))
    return {rel: digest for rel, digest in pairs}


_SCHEMES = ("https", "http", "ftp", "sftp", "doi")  # what pooch downloads from


def fetch_raw(
    dest: Path,
    base_url: str = DEFAULT_BASE_URL,
    on_file: Callable[[str, bool], None] | None = None,
) -> dict[str, str]:
    """Download (or keep, when already correct) every raw file under `dest`; return the statuses.

    Args:
        dest: the raw root to fill (all_data/, train/, val/ are created).
        base_url: URL of the raw root; file URLs are base_url + relative path.
        on_file: called with (relative path, downloaded?) after each file.
    """
    import pooch

    pooch.get_logger().setLevel("WARNING")
    scheme = base_url.split("://", 1)[0].lower() if "://" in base_url else ""
    if scheme not in _SCHEMES:
        raise UsageError(
            f"--base-url {base_url}: downloads use {', '.join(_SCHEMES)} (pooch); for files you already have, "
            "copy all_data/, train/ and val/ into --dest and run `fftool fetch-data` to check them"
        )
    base_url = base_url if base_url.endswith("/") else base_url + "/"
    made = [folder for folder in (dest, *dest.parents) if not folder.exists()]  # deepest first
    dest.mkdir(parents=True, exist_ok=True)
    try:
        return _fill(dest, base_url, on_file)
    except FetchError:
        for folder in made:  # the folders this call made, and only while empty: a failure leaves no trace
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise


def _fill(dest: Path, base_url: str, on_file: Callable[[str, bool], None] | None) -> dict[str, str]:
    """Every raw file under `dest`, downloaded into a staging folder first and moved in only when all are."""
    import pooch

    status: dict[str, str] = {}
    with tempfile.TemporaryDirectory(prefix=".fetch-", dir=dest) as tmp:
        staged: dict[str, Path] = {}
        for rel, digest in registry().items():
            target = dest / rel
            if target.is_file() and sha256_file(target) == digest:
                status[rel] = "present"
            else:
                try:
                    staged[rel] = Path(
                        pooch.retrieve(
                            base_url + rel,
                            known_hash=f"sha256:{digest}",
                            fname=rel.replace("/", "__"),
                            path=tmp,
                            progressbar=False,
                        )
                    )
                except ValueError as exc:  # pooch's checksum mismatch
                    raise FetchError(
                        f"{base_url + rel}: checksum mismatch (expected sha256 {digest[:16]}…); "
                        "nothing was kept. The server may serve a different version of the file."
                    ) from exc
                except Exception as exc:
                    raise FetchError(f"{base_url + rel}: download failed ({exc}); nothing was kept") from exc
                status[rel] = "downloaded"
            if on_file:
                on_file(rel, rel in staged)
        for rel, path in staged.items():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.move(path, dest / rel)
    return status
