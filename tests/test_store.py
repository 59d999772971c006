"""The artifact store: atomic builds, interruption, self-healing, verification, lookup by id."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from fftool.artifacts.hashing import fingerprint
from fftool.artifacts.store import MANIFEST, ArtifactStore
from fftool.errors import ArtifactMissing, FftoolError, IntegrityError, SchemaError

PARAMS, INPUTS = {"p": 1}, {"up": "0" * 64}
FP_A = fingerprint("demo", 1, PARAMS, INPUTS)  # a manifest's fingerprint is that of its own parameters and inputs
# Another demo artifact whose fingerprint shares FP_A's first hex digit only (for prefix lookups).
P_B = next(n for n in range(2, 1000) if (f := fingerprint("demo", 1, {"p": n}, INPUTS))[0] == FP_A[0] != f[1])
FP_B = fingerprint("demo", 1, {"p": P_B}, INPUTS)


def _build(store: ArtifactStore, kind: str = "demo", p: int = 1, content: str = "hello", version: int = 1):
    params = {"p": p}
    with store.build(kind, fingerprint(kind, version, params, INPUTS), schema_version=version, params=params,
                     inputs=INPUTS) as ctx:  # fmt: skip
        (ctx.dir / "data.txt").write_text(content)
        ctx.stats = {"rows": 1}
    return ctx.artifact


def test_build_writes_manifest_with_hashes(store: ArtifactStore) -> None:
    artifact = _build(store)
    manifest = artifact.manifest
    assert artifact.path == store.root / "demo" / FP_A[:16]
    assert manifest.kind == "demo" and manifest.schema_version == 1 and manifest.fingerprint == FP_A
    assert manifest.files["data.txt"]["bytes"] == 5
    assert manifest.params == {"p": 1} and manifest.stats == {"rows": 1}
    assert manifest.created_at and manifest.fftool_version
    assert store.lookup("demo", FP_A) == artifact
    assert store.verify(artifact) == []


def test_the_manifest_records_where_it_was_built(store: ArtifactStore) -> None:
    import torch  # noqa: F401 - a process that uses torch records its version and thread count

    environment = _build(store).manifest.environment
    assert {"python", "platform", "cpu", "cpu_count", "numpy", "torch", "torch_threads"} <= set(environment)
    assert environment["torch_threads"] >= 1 and environment["cpu"]


def test_failed_build_leaves_nothing(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path / "fresh")
    with pytest.raises(RuntimeError), store.build("demo", FP_A, schema_version=1, params=PARAMS, inputs=INPUTS) as ctx:
        (ctx.dir / "half.txt").write_text("half")
        raise RuntimeError("boom")
    assert not (tmp_path / "fresh").exists()


def test_failed_rebuild_keeps_the_old_artifact(store: ArtifactStore) -> None:
    _build(store, content="old")
    with (
        pytest.raises(KeyboardInterrupt),
        store.build("demo", FP_A, schema_version=1, params=PARAMS, inputs=INPUTS) as ctx,
    ):
        (ctx.dir / "data.txt").write_text("new, half written")
        raise KeyboardInterrupt
    artifact = store.lookup("demo", FP_A)
    assert (artifact.path / "data.txt").read_text() == "old"
    assert store.verify(artifact) == []
    assert not (store.root / ".incomplete").exists()


def test_forced_rebuild_replaces_atomically(store: ArtifactStore) -> None:
    _build(store, content="old")
    artifact = _build(store, content="brand new")
    assert (artifact.path / "data.txt").read_text() == "brand new"
    assert [a.id for a in store.list()] == [artifact.id]


KILLED_BUILD = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from fftool.artifacts.hashing import fingerprint
    from fftool.artifacts.store import ArtifactStore
    store = ArtifactStore(sys.argv[1])
    params, inputs = {"p": 1}, {"up": "0" * 64}
    with store.build("demo", fingerprint("demo", 1, params, inputs), schema_version=1, params=params,
                     inputs=inputs) as ctx:
        (ctx.dir / "data.txt").write_text("partial")
        Path(sys.argv[2]).write_text("started")
        time.sleep(60)
    """
)


def test_killed_build_leaves_no_artifact_and_is_cleaned_next_time(store: ArtifactStore, tmp_path: Path) -> None:
    marker = tmp_path / "started"
    proc = subprocess.Popen([sys.executable, "-c", KILLED_BUILD, str(store.root), str(marker)])
    deadline = time.monotonic() + 30
    while not marker.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert marker.exists(), "the build subprocess never started"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert store.lookup("demo", FP_A) is None and store.list() == []
    assert list((store.root / ".incomplete").iterdir())  # the dead process's folder is still there
    artifact = _build(store)  # the next build removes it
    assert store.list() == [artifact]
    assert not (store.root / ".incomplete").exists()


@pytest.mark.parametrize(
    "manifest",
    ["{not json", "[1, 2]", '{"kind": "demo"}', None],
    ids=["not-json", "not-an-object", "keys-missing", "no-manifest"],
)
def test_unreadable_folder_is_reported_never_deleted(store: ArtifactStore, manifest: str | None) -> None:
    artifact = _build(store)
    if manifest is None:
        (artifact.path / MANIFEST).unlink()
    else:
        (artifact.path / MANIFEST).write_text(manifest)
    assert store.list() == []
    with pytest.raises(IntegrityError, match=FP_A[:16]):
        store.lookup("demo", FP_A)
    assert (artifact.path / "data.txt").read_text() == "hello"
    [damaged] = store.damaged()
    assert str(artifact.path) in str(damaged)


def test_manifest_of_a_newer_fftool_is_kept_and_named(store: ArtifactStore) -> None:
    artifact = _build(store)
    data = json.loads((artifact.path / MANIFEST).read_text()) | {"fftool_version": "99.0", "signature": "x"}
    (artifact.path / MANIFEST).write_text(json.dumps(data))
    with pytest.raises(IntegrityError, match=r"unknown keys \['signature'\] \(written by fftool 99.0"):
        store.lookup("demo", FP_A)
    assert artifact.path.exists()


def test_forced_rebuild_sets_an_unreadable_folder_aside(store: ArtifactStore) -> None:
    artifact = _build(store)
    (artifact.path / MANIFEST).write_text("{not json")
    rebuilt = _build(store, content="new")
    assert store.lookup("demo", FP_A) == rebuilt
    [aside] = (store.root / ".damaged").iterdir()
    assert (aside / "data.txt").read_text() == "hello" and (aside / MANIFEST).read_text() == "{not json"


def test_concurrent_builds_of_one_fingerprint_wait_for_each_other(store: ArtifactStore) -> None:
    order: list[str] = []

    def build(name: str) -> None:
        with store.build("demo", FP_A, schema_version=1, params=PARAMS, inputs=INPUTS) as ctx:
            order.append(f"{name} start")
            time.sleep(0.3)
            (ctx.dir / "data.txt").write_text(name)
            order.append(f"{name} end")

    threads = [threading.Thread(target=build, args=(name,)) for name in ("a", "b")]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert order[0].endswith("start") and order[1].endswith("end") and order[1][0] == order[0][0]
    assert store.verify(store.lookup("demo", FP_A)) == []


def test_check_inputs_refuses_a_changed_input(store: ArtifactStore) -> None:
    artifact = _build(store)
    store.check_inputs({"demo": artifact}, {"demo": "fftool demo"})
    (artifact.path / "data.txt").write_text("hellO")
    with pytest.raises(
        IntegrityError, match=rf"artifact demo/{FP_A[:16]} .*data.txt: content changed.*`fftool demo --force`"
    ):
        store.check_inputs({"demo": artifact}, {"demo": "fftool demo"})


def test_chain_walks_inputs_and_names_missing_ones(store: ArtifactStore) -> None:
    up_fp = fingerprint("up", 1, {}, {})
    with store.build("up", up_fp, schema_version=1, params={}, inputs={}) as ctx:
        (ctx.dir / "u.txt").write_text("u")
    upstream = ctx.artifact
    inputs = {"up": up_fp, "raw/x.txt": "0" * 64}
    with store.build("down", fingerprint("down", 1, {}, inputs), schema_version=1, params={}, inputs=inputs) as ctx:
        (ctx.dir / "d.txt").write_text("d")
    down = ctx.artifact
    assert [a.id for a in store.chain(down)] == [down.id, upstream.id]
    shutil.rmtree(upstream.path)
    assert store.chain(down)[1] == f"up/{up_fp[:16]} (an input of {down.id}) is no longer in the store"


@pytest.mark.parametrize("ref", ["../..", "../../etc/passwd", "demo/../../x", "/etc"])
def test_resolve_refuses_paths(store: ArtifactStore, ref: str) -> None:
    _build(store)
    with pytest.raises(FftoolError, match="is not an artifact id"):
        store.resolve(ref)


def test_verify_reports_changed_missing_and_extra_files(store: ArtifactStore) -> None:
    artifact = _build(store)
    (artifact.path / "data.txt").write_text("tampered")
    (artifact.path / "extra.bin").write_bytes(b"x")
    problems = store.verify(artifact)
    assert problems[0].startswith("data.txt: content changed")
    assert problems[1] == "extra.bin: not listed in the manifest"
    (artifact.path / "data.txt").unlink()
    assert store.verify(artifact)[0] == "data.txt: missing"


def test_resolve_by_prefix_kind_and_ambiguity(store: ArtifactStore) -> None:
    a = _build(store)
    b = _build(store, p=P_B)
    other = _build(store, kind="other")
    assert a.fingerprint == FP_A and b.fingerprint == FP_B
    assert store.resolve(f"demo/{FP_A[:4]}") == a
    assert store.resolve(FP_B[:6]) == b
    assert store.resolve("other") == other
    with pytest.raises(FftoolError, match="ambiguous"):
        store.resolve(f"demo/{FP_A[0]}")
    with pytest.raises(ArtifactMissing, match="no artifact matches 'demo/9'"):
        store.resolve("demo/9")


def test_require_names_the_command_and_checks_the_schema(store: ArtifactStore) -> None:
    with pytest.raises(ArtifactMissing, match=r"no 'demo' artifact .* run `fftool ingest` first"):
        store.require("demo", FP_A, 1, "fftool ingest")
    _build(store, version=1)
    with pytest.raises(SchemaError, match=r"schema version 1, this fftool reads version 2; rebuild it with"):
        store.require("demo", FP_A, 2, "fftool ingest")
    assert store.require("demo", FP_A, 1, "fftool ingest").kind == "demo"


def test_a_bare_kind_is_ambiguous_when_several_exist_and_lists_them(store: ArtifactStore) -> None:
    first, second = {"benchmark": "zara1", "variant": "dr"}, {"benchmark": "eth", "variant": "re"}
    fp = fingerprint("cvae", 1, first, {})
    with store.build("cvae", fp, schema_version=1, params=first, inputs={}) as c:
        (c.dir / "m").write_text("a")
    assert store.resolve("cvae").id == f"cvae/{fp[:16]}"  # the only one
    with store.build("cvae", fingerprint("cvae", 1, second, {}), schema_version=1, params=second, inputs={}) as c:
        (c.dir / "m").write_text("b")
    with pytest.raises(FftoolError, match=r"'cvae' is ambiguous, 2 artifacts match: .*\(zara1 · dr\).*\(eth · re\)"):
        store.resolve("cvae")


def test_a_manifest_that_does_not_give_its_own_fingerprint_is_not_trusted(store: ArtifactStore) -> None:
    """An edited manifest (other parameters shown and built on) and a folder copied under another fingerprint
    with its manifest edited to match are refused, on lookup (naming the fields a planned build differs in)
    and by verify."""
    artifact = _build(store)
    data = json.loads((artifact.path / MANIFEST).read_text())
    (artifact.path / MANIFEST).write_text(json.dumps(data | {"params": {"p": 2}}))
    with pytest.raises(IntegrityError, match=r"params\.p differ from this build's.*not trusted"):
        store.lookup("demo", FP_A, planned=(PARAMS, INPUTS))
    assert store.list() == [] and len(store.damaged()) == 1
    (artifact.path / MANIFEST).write_text(json.dumps(data))
    assert store.lookup("demo", FP_A) is not None and store.verify(store.lookup("demo", FP_A)) == []
    copied = store.path_for("demo", FP_B)  # the same bytes, posing as the p = P_B build
    shutil.copytree(artifact.path, copied)
    (copied / MANIFEST).write_text(json.dumps(data | {"fingerprint": FP_B}))
    with pytest.raises(IntegrityError, match=rf"give fingerprint {FP_A[:16]}, not the {FP_B[:16]}.*params\.p differ"):
        store.lookup("demo", FP_B, planned=({"p": P_B}, INPUTS))
