"""Fingerprints: independent of key order, sensitive to version, parameters and inputs."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from fftool.artifacts.hashing import canonical_json, fingerprint

params_strategy = st.dictionaries(
    st.text(min_size=1, max_size=8), st.one_of(st.integers(), st.text(max_size=5), st.booleans()), max_size=6
)


@given(params_strategy)
def test_fingerprint_ignores_key_order(params: dict) -> None:
    reordered = dict(reversed(list(params.items())))
    assert canonical_json(params) == canonical_json(reordered)
    assert fingerprint("s", 1, params, {}) == fingerprint("s", 1, reordered, {})


def test_fingerprint_changes_with_version_params_and_inputs() -> None:
    base = fingerprint("windows", 1, {"obs_len": 8}, {"tracks": "a" * 64})
    assert fingerprint("windows", 2, {"obs_len": 8}, {"tracks": "a" * 64}) != base
    assert fingerprint("windows", 1, {"obs_len": 9}, {"tracks": "a" * 64}) != base
    assert fingerprint("windows", 1, {"obs_len": 8}, {"tracks": "b" * 64}) != base
    assert fingerprint("forces", 1, {"obs_len": 8}, {"tracks": "a" * 64}) != base
