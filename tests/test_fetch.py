"""fetch-data against a local HTTP server on 127.0.0.1 that serves the real raw files."""

from __future__ import annotations

import functools
import shutil
import threading
from collections.abc import Iterator
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest
from typer.testing import CliRunner

from fftool.artifacts.hashing import sha256_file
from fftool.cli import app
from fftool.dataset.fetch import fetch_raw, registry
from fftool.errors import FetchError


class _QuietHandler(SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: object) -> None:
        pass


@pytest.fixture
def serve() -> Iterator:
    """serve(folder) -> base URL of a loopback HTTP server for that folder; stopped after the test."""
    servers = []

    def start(folder: Path) -> str:
        server = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_QuietHandler, directory=str(folder)))
        threading.Thread(target=server.serve_forever, daemon=True).start()
        servers.append(server)
        return f"http://127.0.0.1:{server.server_address[1]}"

    yield start
    for server in servers:
        server.shutdown()
        server.server_close()


def test_registry_pins_all_24_files() -> None:
    assert len(registry()) == 24
    assert all(len(digest) == 64 for digest in registry().values())


@pytest.mark.data
def test_fetch_downloads_verifies_and_places(real_raw: Path, serve, tmp_path: Path) -> None:
    base = serve(real_raw.parent) + "/raw/"
    dest = tmp_path / "raw"
    status = fetch_raw(dest, base)
    assert set(status.values()) == {"downloaded"} and len(status) == 24
    for rel, digest in registry().items():
        assert sha256_file(dest / rel) == digest
    assert sorted(p.name for p in dest.iterdir()) == ["all_data", "train", "val"]  # no temp folders left
    again = fetch_raw(dest, base)
    assert set(again.values()) == {"present"}


@pytest.mark.data
def test_corrupted_file_is_a_clear_error_and_nothing_is_kept(real_raw: Path, serve, tmp_path: Path) -> None:
    mirror = tmp_path / "mirror"
    shutil.copytree(real_raw, mirror / "raw")
    target = mirror / "raw" / "train" / "students001_train.txt"
    target.chmod(0o644)
    target.write_bytes(target.read_bytes().replace(b"1", b"7", 1))
    base = serve(mirror) + "/raw/"
    dest = tmp_path / "dest"
    with pytest.raises(FetchError, match=r"train/students001_train\.txt: checksum mismatch .* nothing was kept"):
        fetch_raw(dest, base)
    assert [p for p in dest.rglob("*")] == []


def test_fetch_cli_reports_failure_with_exit_1(serve, tmp_path: Path) -> None:
    base = serve(tmp_path) + "/nothing-here/"
    result = CliRunner().invoke(app, ["fetch-data", "--dest", str(tmp_path / "d" / "raw"), "--base-url", base])
    assert result.exit_code == 1
    assert "Error: " in result.output and "download failed" in result.output and "nothing was kept" in result.output
    assert not (tmp_path / "d").exists()  # nor the folders it made for it


@pytest.mark.data
def test_fetch_cli_then_ingest(real_raw: Path, serve, tmp_path: Path) -> None:
    base = serve(real_raw.parent) + "/raw/"
    runner = CliRunner()
    result = runner.invoke(app, ["fetch-data", "--dest", str(tmp_path / "raw"), "--base-url", base])
    assert result.exit_code == 0, result.output
    assert "24 downloaded" in result.output
    ingest = runner.invoke(app, ["ingest", "--raw", str(tmp_path / "raw"), "--root", str(tmp_path / "artifacts")])
    assert ingest.exit_code == 0, ingest.output


def test_an_unsupported_url_scheme_is_a_usage_error_not_a_checksum_mismatch(tmp_path: Path) -> None:
    from fftool.dataset.fetch import fetch_raw
    from fftool.errors import UsageError

    with pytest.raises(UsageError, match=r"--base-url file:///x: downloads use https"):
        fetch_raw(tmp_path / "raw", "file:///x")
    assert not (tmp_path / "raw").exists()
