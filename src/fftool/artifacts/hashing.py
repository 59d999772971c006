"""Canonical JSON, file hashes and artifact fingerprints (DESIGN §7).

A fingerprint chains the stage name, its schema version, the resolved parameters and the fingerprints
(or content hashes) of its inputs, so any change upstream changes everything downstream.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

_CHUNK = 1 << 20


def canonical_json(value: Any) -> str:
    """JSON with sorted keys and no whitespace: equal data gives equal text, whatever the key order."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(_CHUNK), b""):
            digest.update(chunk)
    return digest.hexdigest()


def fingerprint(stage: str, version: int, params: Mapping[str, Any], inputs: Mapping[str, str]) -> str:
    """sha256 of the canonical JSON of everything that determines a stage's output."""
    payload = {"stage": stage, "version": version, "params": dict(params), "inputs": dict(inputs)}
    return sha256_bytes(canonical_json(payload).encode())
