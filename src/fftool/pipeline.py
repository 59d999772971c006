"""The stage DAG: fingerprints, skip-if-built, atomic builds, in dependency order.

    raw ETH/UCY txt ──▶ tracks ──▶ windows ──▶ forces
                          └──────────────────────▲
    scene images + homographies ──▶ maps ──▶ goal (per benchmark) ──▶ goals (per benchmark)
                                   windows ──┘
    windows + forces ──▶ cvae (per benchmark and variant)
    windows + forces (+ cvae, + goals, as the predictor needs) ──▶ evaluate (per benchmark)

Worked example: `run(cfg, store, ["windows"])` plans `[tracks, windows]`; for each stage it asks the
declaration (`STAGE.declare(cfg)`, a `Reads`) what the build reads, computes fingerprint(stage, version,
the declared parameters, upstream fingerprints (or views of them) and raw-file hashes), skips the stage
when `<root>/<stage>/<fp[:16]>/` holds a complete artifact, and otherwise builds it atomically, handing
`build` a configuration view that refuses every key it did not declare. Each stage module declares itself
(fftool.stages.contract); this engine holds no per-stage code and is the only module that knows every
stage. Stages never import each other.
"""

from __future__ import annotations

import contextlib
import functools
import tempfile
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fftool.artifacts.hashing import fingerprint
from fftool.artifacts.store import Artifact, ArtifactStore, check_schema
from fftool.config import PipelineConfig, benchmark_names, variant_section
from fftool.errors import FftoolError, UsageError
from fftool.learning import distributed
from fftool.stages import cvae, dlow, evaluate, forces, goal, goals, maps, tracks, windows
from fftool.stages.contract import ConfigView, Reads, Stage, StageContext, allowed_keys
from fftool.ui import log, progress, warn


@dataclass(frozen=True)
class Runtime:
    """How to run, not what to compute: never part of a fingerprint."""

    device: str = "auto"  # auto | cpu | cuda


STAGES: dict[str, Stage] = {
    module.STAGE.name: module.STAGE for module in (tracks, windows, forces, maps, goal, goals, cvae, dlow, evaluate)
}


@dataclass(frozen=True)
class Resolved:
    """A planned stage build with everything its fingerprint is made of, all from its declaration."""

    stage: Stage
    reads: Reads  # what the build reads (STAGE.declare)
    params: dict[str, Any]  # the declared configuration values (and the benchmark), as hashed
    inputs: dict[str, str]  # what the fingerprint hashes: upstream stage (or view of it) -> fp, raw file -> sha256
    sources: dict[str, str]  # the upstream artifacts it is built from: stage -> full fingerprint
    allowed: frozenset[str]  # the "section.key"s the build may read: declared, or hashed through an upstream view
    fingerprint: str
    benchmark: str | None

    @property
    def command_line(self) -> str:
        return self.stage.command_line(self.reads, self.benchmark)

    @property
    def description(self) -> str:
        return self.stage.describe(self.reads, self.benchmark)

    def config_view(self, cfg: PipelineConfig) -> ConfigView:
        """The configuration `build` gets: the keys this build declared, and no other."""
        return ConfigView(cfg, self.allowed, self.stage.name)


def _stage(name: str) -> Stage:
    if name not in STAGES:
        raise FftoolError(f"unknown stage {name!r}; stages: {', '.join(STAGES)}")
    return STAGES[name]


def resolve(
    cfg: PipelineConfig,
    targets: Iterable[str],
    benchmark: str | None = None,
    recorded: Mapping[str, Mapping[str, str]] | None = None,
) -> list[Resolved]:
    """The builds `targets` need under `cfg`, upstream first, each once, each fingerprinted from its
    declaration: its parameters, and its upstream fingerprints (or views of them) and raw-file hashes.
    recorded: stage -> raw-file hashes to use instead of hashing that stage's files (a shipped model's
    lineage, where the benchmark data is not at hand)."""
    resolved: dict[str, Resolved] = {}

    def visit(name: str) -> None:
        if name in resolved:
            return
        stage = _stage(name)
        reads = stage.declare(cfg)
        for upstream in reads.artifacts:
            visit(upstream)
        declared = allowed_keys(cfg, reads.params)
        params = _record(cfg, stage, declared)
        if stage.per_benchmark:
            offered = benchmark_names(cfg)
            if benchmark not in offered:  # a usage error: the command line or profile named it (exit 2)
                given = "no benchmark" if benchmark is None else f"benchmark {benchmark!r}"
                raise UsageError(f"stage {stage.name!r} got {given}; the data offers {', '.join(offered)}")
            params["benchmark"] = benchmark
        ups = {up: resolved[up] for up in reads.artifacts}
        raw = (recorded or {}).get(name)
        inputs = dict(_input_key(ups[up], parts) for up, parts in reads.artifacts.items()) | dict(
            reads.raw_files() if raw is None else raw
        )
        allowed = declared | allowed_keys(cfg, reads.locations)
        for up, parts in reads.artifacts.items():
            if parts is not None and ups[up].stage.section:
                allowed |= {f"{ups[up].stage.section}.{key}" for key in ups[up].stage.view_keys(parts)}
        sources = {up: item.fingerprint for up, item in ups.items()}
        fp = fingerprint(stage.name, stage.version, params, inputs)
        where = benchmark if stage.per_benchmark else None
        resolved[name] = Resolved(stage, reads, params, inputs, sources, allowed, fp, where)

    for target in targets:
        visit(target)
    return list(resolved.values())


def _record(cfg: PipelineConfig, stage: Stage, declared: frozenset[str]) -> dict[str, Any]:
    """The declared configuration values ("section.key", from Reads.params) as the fingerprint hashes them: the
    stage's own section under bare names, its keys the build does not read at their defaults; others as is."""
    record: dict[str, Any] = {}
    if stage.section is not None:
        section = variant_section(cfg, stage.section)
        defaults = type(section)().model_dump(mode="json")
        values = section.model_dump(mode="json")
        record = {key: values[key] if f"{stage.section}.{key}" in declared else defaults[key] for key in values}
    for dotted in sorted(declared):
        name, key = dotted.split(".")
        if name != stage.section:
            record[dotted] = variant_section(cfg, name).model_dump(mode="json")[key]
    return record


def _input_key(upstream: Resolved, parts: tuple[str, ...] | None) -> tuple[str, str]:
    """How a consumer's fingerprint names an upstream artifact: by its fingerprint, or, when the consumer
    reads only some parts of it, by a fingerprint of the parameters those parts depend on, so
    `forces.fov_deg` reaches the models that read the repulsive force and no other."""
    stage = upstream.stage
    if parts is None:
        return stage.name, upstream.fingerprint
    keys = stage.view_keys(parts)
    view = {key: value for key, value in upstream.params.items() if key in keys}
    return f"{stage.name}[{','.join(sorted(parts))}]", fingerprint(stage.name, stage.version, view, upstream.inputs)


class Built(dict[str, Artifact]):
    """What `run` made or found, stage -> artifact, and `new`: the stages it built now, with their seconds."""

    def __init__(self) -> None:
        super().__init__()
        self.new: dict[str, float] = {}


def run(
    cfg: PipelineConfig,
    store: ArtifactStore,
    targets: Iterable[str],
    force: Iterable[str] = (),
    runtime: Runtime | None = None,
    upstream: bool = True,
    benchmark: str | None = None,
) -> Built:
    """Build what is missing for `targets` (and rebuild the stages named in `force`).

    With `upstream=False` (a single stage's command) the stages before the targets are not built:
    their artifacts must exist, else the error names the command that makes them.
    """
    forced, targets, runtime = set(force), list(targets), runtime or Runtime()
    built = Built()
    for item in resolve(cfg, targets, benchmark):
        stage, fp = item.stage, item.fingerprint
        if not upstream and stage.name not in targets:
            built[stage.name] = store.require(stage.name, fp, stage.version, item.command_line)
            continue
        if stage.distributed and not distributed.leader():  # a torchrun rank > 0: rank 0 decides and installs
            built[stage.name] = _follow(cfg, store, item, built, runtime)
            continue
        existing = None if stage.name in forced else _cached(store, item)
        if existing is not None and stage.name in targets:  # the caller reads it: check its bytes first
            store.check_inputs({stage.name: existing})
        if existing is None:
            with store.lock(stage.name, fp):  # another process may have built it while we waited
                existing = None if stage.name in forced else _cached(store, item)
                if existing is None:
                    started = time.perf_counter()
                    existing = _build(cfg, store, item, built, runtime)
                    built.new[stage.name] = time.perf_counter() - started
                else:
                    _announce(stage, runtime, None)
        else:
            _announce(stage, runtime, None)
        built[stage.name] = existing
    return built


def _cached(store: ArtifactStore, item: Resolved) -> Artifact | None:
    """The built artifact of a planned build, or None; one whose manifest does not give its own fingerprint is
    refused, naming the parameters or inputs it records other than the plan's."""
    stage, fp = item.stage, item.fingerprint
    existing = store.lookup(stage.name, fp, planned=(item.params, item.inputs))
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
) -> Artifact:
    """Build one stage from verified inputs (their files are re-hashed first; the time it takes is recorded),
    handing it the configuration view of its declaration."""
    stage, fp = item.stage, item.fingerprint
    log(f"stage {stage.name!r}: building (fp {fp[:12]}…)")
    inputs = {name: built[name] for name in item.reads.artifacts}
    started = time.perf_counter()
    store.check_inputs(inputs)
    checked_s = time.perf_counter() - started
    with _naming_os_errors(item, store.root), progress() as bar:
        task = bar.add_task(item.description, total=None)
        context = functools.partial(
            StageContext,
            benchmark=item.benchmark,
            device_name=runtime.device,
            on_progress=lambda phase, done, total: bar.update(task, completed=done, total=total, description=phase),
            on_epoch=lambda row: bar.console.print("  " + "  ".join(_cell(k, v) for k, v in row.items())),
        )
        with store.build(
            stage.name,
            fp,
            schema_version=stage.version,
            params=item.params,
            inputs=item.inputs,
            sources=item.sources,
            context=context,
        ) as ctx:
            _announce(stage, runtime, ctx.scratch)
            stats = stage.build(item.config_view(cfg), inputs, ctx)
            for message in stats.get("warnings", []):  # a stage's warnings stay in its manifest too
                warn(message)
            build_s = time.perf_counter() - started - checked_s
            ctx.stats = stats | {"input_check_seconds": round(checked_s, 4), "build_seconds": round(build_s, 3)}
    assert ctx.artifact is not None
    if stage.distributed:
        distributed.barrier()  # the other ranks read the installed artifact
    log(f"stage {stage.name!r}: wrote {ctx.artifact.path}")
    return ctx.artifact


@contextlib.contextmanager
def _naming_os_errors(item: Resolved, root: Path) -> Iterator[None]:
    """A build's OSError (a full disk, a read-only root) as one error naming the stage and the file."""
    try:
        yield
    except OSError as exc:
        if isinstance(exc, FftoolError):
            raise
        raise FftoolError(
            f"stage {item.stage.name!r} ({item.description}): {exc.filename or root}: {exc.strerror or exc}; "
            "no partial artifact was kept"
        ) from exc


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
) -> Artifact:
    """A data-parallel stage on a torchrun rank other than 0: train beside rank 0, which alone takes the lock,
    writes checkpoints and logs and installs, into a throwaway folder; then read what rank 0 installed."""
    stage = item.stage
    distributed.join(runtime.device)
    scratch = distributed.broadcast(None)
    if scratch is not None:
        inputs = {name: built[name] for name in item.reads.artifacts}
        with tempfile.TemporaryDirectory(prefix=f"fftool-rank{distributed.rank()}-") as tmp:
            ctx = StageContext(Path(tmp), Path(scratch), benchmark=item.benchmark, device_name=runtime.device)
            stage.build(item.config_view(cfg), inputs, ctx)
        distributed.barrier()  # rank 0 has installed the artifact
    return store.require(stage.name, item.fingerprint, stage.version, item.command_line)


def _cell(key: str, value: Any) -> str:
    """One `key value` of an epoch's printed line (logs show progress where no live bar is drawn)."""
    return f"{key} {value:.4g}" if isinstance(value, float) else f"{key} {value}"
