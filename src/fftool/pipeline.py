"""The stage DAG: fingerprints, skip-if-built, atomic builds, in dependency order.

    raw ETH/UCY txt ──▶ tracks ──▶ windows ──▶ forces
                          └──────────────────────▲
    scene images + homographies ──▶ maps ──▶ goal (per benchmark) ──▶ goals (per benchmark)
                                   windows ──┘
    windows + forces ──▶ cvae (per benchmark and variant)
    windows + forces (+ cvae, + goals, as the predictor needs) ──▶ evaluate (per benchmark)

Worked example: `run(cfg, store, ["windows"])` plans `[tracks, windows]`; for each stage it computes
fingerprint(stage, VERSION, its config section, upstream fingerprints or raw-file hashes), skips the
stage when `<root>/<stage>/<fp[:16]>/` holds a complete artifact, and builds it atomically otherwise.
Each stage module declares itself (`STAGE`, fftool.stages.contract); this engine holds no per-stage code
and is the only module that knows every stage. Stages never import each other.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fftool.artifacts.hashing import fingerprint
from fftool.artifacts.store import Artifact, ArtifactStore, check_schema
from fftool.config import PipelineConfig, benchmark_names
from fftool.errors import FftoolError, UsageError
from fftool.learning import distributed
from fftool.stages import cvae, evaluate, forces, goal, goals, maps, tracks, windows
from fftool.stages.contract import Stage, StageContext
from fftool.ui import log, progress, warn


@dataclass(frozen=True)
class Runtime:
    """How to run, not what to compute: never part of a fingerprint."""

    device: str = "auto"  # auto | cpu | cuda


STAGES: dict[str, Stage] = {
    module.STAGE.name: module.STAGE for module in (tracks, windows, forces, maps, goal, goals, cvae, evaluate)
}


def plan(targets: Iterable[str], cfg: PipelineConfig | None = None) -> list[Stage]:
    """Stages needed for `targets` (under `cfg`, when inputs depend on it), upstream first, each once."""
    ordered: list[Stage] = []

    def visit(name: str) -> None:
        if name not in STAGES:
            raise FftoolError(f"unknown stage {name!r}; stages: {', '.join(STAGES)}")
        stage = STAGES[name]
        for upstream in stage.inputs_for(cfg):
            visit(upstream)
        if stage not in ordered:
            ordered.append(stage)

    for target in targets:
        visit(target)
    return ordered


@dataclass(frozen=True)
class Resolved:
    """A planned stage with everything its fingerprint is made of."""

    stage: Stage
    params: dict[str, Any]
    inputs: dict[str, str]  # what the fingerprint hashes: upstream stage (or view of it) -> fp, raw file -> sha256
    sources: dict[str, str]  # the upstream artifacts it is built from: stage -> full fingerprint
    fingerprint: str


def resolve(cfg: PipelineConfig, targets: Iterable[str], benchmark: str | None = None) -> list[Resolved]:
    """Plan `targets` and fingerprint each stage; upstream fingerprints chain into downstream ones."""
    resolved: dict[str, Resolved] = {}
    for stage in plan(targets, cfg):
        params = stage.section(cfg).model_dump(mode="json")
        if stage.per_benchmark:
            offered = benchmark_names(cfg)
            if benchmark not in offered:  # a usage error: the command line or profile named it (exit 2)
                given = "no benchmark" if benchmark is None else f"benchmark {benchmark!r}"
                raise UsageError(f"stage {stage.name!r} got {given}; the data offers {', '.join(offered)}")
            params["benchmark"] = benchmark
        upstream = [resolved[name] for name in stage.inputs_for(cfg)]
        inputs = dict(_input_key(up, stage.reads(cfg).get(up.stage.name)) for up in upstream)
        inputs |= stage.external_inputs(cfg)
        sources = {up.stage.name: up.fingerprint for up in upstream}
        fp = fingerprint(stage.name, stage.version, params, inputs)
        resolved[stage.name] = Resolved(stage, params, inputs, sources, fp)
    return list(resolved.values())


def _input_key(upstream: Resolved, parts: tuple[str, ...] | None) -> tuple[str, str]:
    """How a consumer's fingerprint names an upstream artifact: by its fingerprint, or, when the consumer
    reads only some parts of it (`Stage.reads`), by a fingerprint of the parameters those parts depend on
    (`Stage.view`), so `forces.fov_deg` reaches the models that read the repulsive force and no other."""
    stage = upstream.stage
    if parts is None or stage.view is None:
        return stage.name, upstream.fingerprint
    view = fingerprint(stage.name, stage.version, stage.view(upstream.params, parts), upstream.inputs)
    return f"{stage.name}[{','.join(sorted(parts))}]", view


def run(
    cfg: PipelineConfig,
    store: ArtifactStore,
    targets: Iterable[str],
    force: Iterable[str] = (),
    runtime: Runtime | None = None,
    upstream: bool = True,
    benchmark: str | None = None,
) -> dict[str, Artifact]:
    """Build what is missing for `targets` (and rebuild the stages named in `force`).

    With `upstream=False` (a single stage's command) the stages before the targets are not built:
    their artifacts must exist, else the error names the command that makes them.
    """
    forced, targets = set(force), list(targets)
    built: dict[str, Artifact] = {}
    for item in resolve(cfg, targets, benchmark):
        stage, fp = item.stage, item.fingerprint
        if not upstream and stage.name not in targets:
            built[stage.name] = store.require(stage.name, fp, stage.version, stage.command_line(cfg, benchmark))
            continue
        if stage.distributed and not distributed.leader():  # a torchrun rank > 0: rank 0 decides and installs
            built[stage.name] = _follow(cfg, store, item, built, runtime or Runtime(), benchmark)
            continue
        existing = None if stage.name in forced else _cached(store, stage, fp)
        if existing is not None and stage.name in targets:  # the caller reads it: check its bytes first
            store.check_inputs({stage.name: existing}, {stage.name: stage.command})
        if existing is None:
            with store.lock(stage.name, fp):  # another process may have built it while we waited
                existing = None if stage.name in forced else _cached(store, stage, fp)
                if existing is None:
                    existing = _build(cfg, store, item, built, runtime or Runtime(), benchmark)
                else:
                    _announce(stage, runtime or Runtime(), None)
        else:
            _announce(stage, runtime or Runtime(), None)
        built[stage.name] = existing
    return built


def _cached(store: ArtifactStore, stage: Stage, fp: str) -> Artifact | None:
    existing = store.lookup(stage.name, fp)
    if existing is not None:
        check_schema(existing, stage.name, stage.version, stage.command)
        log(f"stage {stage.name!r} is cached (fp {fp[:12]}…) - skipping")
    return existing


def _build(
    cfg: PipelineConfig,
    store: ArtifactStore,
    item: Resolved,
    built: Mapping[str, Artifact],
    runtime: Runtime,
    benchmark: str | None,
) -> Artifact:
    """Build one stage from verified inputs (their files are re-hashed first; the time it takes is recorded)."""
    stage, fp = item.stage, item.fingerprint
    log(f"stage {stage.name!r}: building (fp {fp[:12]}…)")
    inputs = {name: built[name] for name in stage.inputs_for(cfg)}
    started = time.perf_counter()
    store.check_inputs(inputs, {name: STAGES[name].command for name in inputs})
    checked_s = time.perf_counter() - started
    with (
        store.build(
            stage.name, fp, schema_version=stage.version, params=item.params, inputs=item.inputs, sources=item.sources
        ) as built_ctx,
        progress() as bar,
    ):
        task = bar.add_task(stage.description(cfg, benchmark), total=None)
        ctx = StageContext(
            out_dir=built_ctx.dir,
            scratch=built_ctx.scratch,
            benchmark=benchmark,
            device_name=runtime.device,
            on_progress=lambda phase, done, total: bar.update(task, completed=done, total=total, description=phase),
            on_epoch=lambda row: bar.console.print("  " + "  ".join(_cell(k, v) for k, v in row.items())),
        )
        _announce(stage, runtime, built_ctx.scratch)
        stats = stage.build(cfg, inputs, ctx)
        for message in stats.get("warnings", []):  # a stage's warnings stay in its manifest too
            warn(message)
        build_s = time.perf_counter() - started - checked_s
        built_ctx.stats = stats | {"input_check_seconds": round(checked_s, 4), "build_seconds": round(build_s, 3)}
    assert built_ctx.artifact is not None
    if stage.distributed:
        distributed.barrier()  # the other ranks read the installed artifact
    log(f"stage {stage.name!r}: wrote {built_ctx.artifact.path}")
    return built_ctx.artifact


def _announce(stage: Stage, runtime: Runtime, scratch: Path | None) -> None:
    """Rank 0 of a torchrun run tells the other ranks whether it trains (in `scratch`, the resume folder they
    share) or found the artifact built (None); a no-op for a single process."""
    if stage.distributed and distributed.active():
        distributed.join(runtime.device)
        distributed.broadcast(None if scratch is None else str(scratch))


def _follow(
    cfg: PipelineConfig,
    store: ArtifactStore,
    item: Resolved,
    built: Mapping[str, Artifact],
    runtime: Runtime,
    benchmark: str | None,
) -> Artifact:
    """A data-parallel stage on a torchrun rank other than 0: train beside rank 0, which alone takes the lock,
    writes checkpoints and logs and installs, into a throwaway folder; then read what rank 0 installed."""
    stage = item.stage
    distributed.join(runtime.device)
    scratch = distributed.broadcast(None)
    if scratch is not None:
        inputs = {name: built[name] for name in stage.inputs_for(cfg)}
        with tempfile.TemporaryDirectory(prefix=f"fftool-rank{distributed.rank()}-") as tmp:
            ctx = StageContext(Path(tmp), Path(scratch), benchmark, runtime.device)
            stage.build(cfg, inputs, ctx)
        distributed.barrier()  # rank 0 has installed the artifact
    return store.require(stage.name, item.fingerprint, stage.version, stage.command_line(cfg, benchmark))


def _cell(key: str, value: Any) -> str:
    """One `key value` of an epoch's printed line (logs show progress where no live bar is drawn)."""
    return f"{key} {value:.4g}" if isinstance(value, float) else f"{key} {value}"
