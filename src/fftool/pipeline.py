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
Only this module knows every stage; stages never import each other.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from fftool import cvae, evaluate, forces, goal, goals, ingest, maps, windows
from fftool.config import PipelineConfig
from fftool.errors import FftoolError
from fftool.hashing import fingerprint
from fftool.scenes import BENCHMARKS
from fftool.store import Artifact, ArtifactStore, BuildContext, check_schema
from fftool.ui import log, progress, warn


@dataclass(frozen=True)
class Runtime:
    """How to run, not what to compute: never part of a fingerprint."""

    device: str = "auto"  # auto | cpu | cuda

    def torch_device(self) -> Any:
        import torch

        if self.device == "auto":
            return torch.device("cuda" if torch.cuda.is_available() else "cpu")
        if self.device == "cuda" and not torch.cuda.is_available():
            raise FftoolError("--device cuda was asked for, but torch sees no CUDA device; use --device auto or cpu")
        return torch.device(self.device)


Builder = Callable[[PipelineConfig, Mapping[str, Artifact], BuildContext, Runtime, "str | None"], dict[str, Any]]


@dataclass(frozen=True)
class Stage:
    """One node of the DAG: what it is called, what it reads, how it is configured and built."""

    name: str
    version: int
    inputs: tuple[str, ...]
    command: str  # the CLI command that makes it, for error messages
    section: Callable[[PipelineConfig], BaseModel]
    build: Builder
    external_inputs: Callable[[PipelineConfig], dict[str, str]] = lambda cfg: {}
    per_benchmark: bool = False  # one artifact per leave-one-out benchmark (the benchmark is a parameter)
    # Upstream stages that depend on the configuration (a subset of `inputs`); default: all of them.
    needs: Callable[[PipelineConfig], tuple[str, ...]] | None = None

    def inputs_for(self, cfg: PipelineConfig | None) -> tuple[str, ...]:
        return self.inputs if self.needs is None or cfg is None else self.needs(cfg)


def _build_tracks(
    cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: BuildContext, runtime: Runtime, benchmark: str | None
) -> dict[str, Any]:
    raw_dir = Path(cfg.data.raw_dir)
    with progress() as bar:
        task = bar.add_task("ingest raw files", total=24)
        stats = ingest.build(cfg.ingest, raw_dir, ctx.dir, on_file=lambda _: bar.advance(task))
    for message in stats["warnings"]:
        warn(message)
    return stats


def _build_windows(
    cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: BuildContext, runtime: Runtime, benchmark: str | None
) -> dict[str, Any]:
    return windows.build(cfg.windows, inputs["tracks"], ctx.dir)


def _build_forces(
    cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: BuildContext, runtime: Runtime, benchmark: str | None
) -> dict[str, Any]:
    files = {source for row in inputs["windows"].manifest.stats["summary"] for source in row["sources"]}
    with progress() as bar:
        task = bar.add_task("social forces", total=len(files))
        stats = forces.build(
            cfg.forces,
            inputs["tracks"],
            inputs["windows"],
            ctx.dir,
            device=runtime.torch_device(),
            on_sequence=lambda name, _: bar.update(task, advance=1, description=f"social forces: {name}"),
        )
    return stats


def _build_maps(
    cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: BuildContext, runtime: Runtime, benchmark: str | None
) -> dict[str, Any]:
    stats = maps.build(cfg.maps, Path(cfg.data.scenes_dir), ctx.dir)
    for message in stats["warnings"]:
        warn(message)
    return stats


def _bar_callback(bar: Any, task: Any) -> Callable[[str, int, int], None]:
    return lambda phase, done, total: bar.update(task, completed=done, total=total, description=phase)


def _epoch_line(bar: Any) -> Callable[[dict[str, Any]], None]:
    """One printed line per epoch, so logs show progress where no live bar is drawn (CI, nohup)."""
    return lambda row: bar.console.print(
        "  " + "  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items())
    )


def _train(description: str, build: Callable[..., dict[str, Any]], *args: Any) -> dict[str, Any]:
    """Run a training stage with a live bar (per batch) and a printed line per epoch."""
    with progress() as bar:
        task = bar.add_task(description, total=None)
        return build(*args, on_progress=_bar_callback(bar, task), on_epoch=_epoch_line(bar))


def _build_goal(
    cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: BuildContext, runtime: Runtime, benchmark: str | None
) -> dict[str, Any]:
    assert benchmark is not None
    return _train(
        f"train goal U-Net ({benchmark})",
        goal.build,
        cfg.goal,
        cfg.goals,
        benchmark,
        inputs["windows"],
        inputs["maps"],
        ctx.dir,
        ctx.scratch,
        runtime.torch_device(),
    )


def _build_cvae(
    cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: BuildContext, runtime: Runtime, benchmark: str | None
) -> dict[str, Any]:
    assert benchmark is not None
    return _train(
        f"train CVAE {cfg.cvae.variant} ({benchmark})",
        cvae.build,
        cfg.cvae,
        cfg.forces,
        benchmark,
        inputs["windows"],
        inputs["forces"],
        ctx.dir,
        ctx.scratch,
        runtime.torch_device(),
    )


def _with_bar(description: str, build: Callable[..., dict[str, Any]], *args: Any) -> dict[str, Any]:
    """Run a stage that reports (phase, done, total) with a live bar."""
    with progress() as bar:
        task = bar.add_task(description, total=None)
        return build(*args, on_progress=_bar_callback(bar, task))


def _build_goals(
    cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: BuildContext, runtime: Runtime, benchmark: str | None
) -> dict[str, Any]:
    assert benchmark is not None
    device = runtime.torch_device()
    args = (cfg.goals, benchmark, inputs["goal"], inputs["windows"], inputs["maps"], ctx.dir, device)
    return _with_bar(f"sample goals ({benchmark})", goals.build, *args)


def _build_evaluate(
    cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: BuildContext, runtime: Runtime, benchmark: str | None
) -> dict[str, Any]:
    assert benchmark is not None
    upstream = (inputs["windows"], inputs["forces"], inputs.get("cvae"), inputs.get("goals"))
    args = (cfg.evaluate, benchmark, *upstream, ctx.dir, runtime.torch_device())
    return _with_bar(f"evaluate ({benchmark})", evaluate.build, *args)


STAGES: dict[str, Stage] = {
    stage.name: stage
    for stage in (
        Stage(
            ingest.NAME,
            ingest.VERSION,
            (),
            "fftool ingest",
            lambda cfg: cfg.ingest,
            _build_tracks,
            lambda cfg: ingest.raw_input_hashes(Path(cfg.data.raw_dir)),
        ),
        Stage(windows.NAME, windows.VERSION, windows.INPUTS, "fftool ingest", lambda cfg: cfg.windows, _build_windows),
        Stage(forces.NAME, forces.VERSION, forces.INPUTS, "fftool forces", lambda cfg: cfg.forces, _build_forces),
        Stage(
            maps.NAME,
            maps.VERSION,
            maps.INPUTS,
            "fftool maps",
            lambda cfg: cfg.maps,
            _build_maps,
            lambda cfg: maps.scene_input_hashes(Path(cfg.data.scenes_dir)),
        ),
        Stage(
            goal.NAME,
            goal.VERSION,
            goal.INPUTS,
            "fftool train-goal",
            lambda cfg: cfg.goal,
            _build_goal,
            per_benchmark=True,
        ),
        Stage(
            goals.NAME,
            goals.VERSION,
            goals.INPUTS,
            "fftool sample-goals",
            lambda cfg: cfg.goals,
            _build_goals,
            per_benchmark=True,
        ),
        Stage(
            cvae.NAME,
            cvae.VERSION,
            cvae.INPUTS,
            "fftool train-cvae",
            lambda cfg: cfg.cvae,
            _build_cvae,
            per_benchmark=True,
        ),
        Stage(
            evaluate.NAME,
            evaluate.VERSION,
            ("windows", "forces", "cvae", "goals"),
            "fftool evaluate",
            evaluate.section,
            _build_evaluate,
            per_benchmark=True,
            needs=evaluate.inputs,
        ),
    )
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
    inputs: dict[str, str]  # upstream stage -> fingerprint, raw file -> sha256
    fingerprint: str


def resolve(cfg: PipelineConfig, targets: Iterable[str], benchmark: str | None = None) -> list[Resolved]:
    """Plan `targets` and fingerprint each stage; upstream fingerprints chain into downstream ones."""
    resolved: dict[str, Resolved] = {}
    for stage in plan(targets, cfg):
        params = stage.section(cfg).model_dump(mode="json")
        if stage.per_benchmark:
            if benchmark not in BENCHMARKS:
                raise FftoolError(f"stage {stage.name!r} needs a benchmark, one of {', '.join(BENCHMARKS)}")
            params["benchmark"] = benchmark
        inputs = {name: resolved[name].fingerprint for name in stage.inputs_for(cfg)} | stage.external_inputs(cfg)
        resolved[stage.name] = Resolved(stage, params, inputs, fingerprint(stage.name, stage.version, params, inputs))
    return list(resolved.values())


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
            built[stage.name] = store.require(stage.name, fp, stage.version, stage.command)
            continue
        existing = None if stage.name in forced else _cached(store, stage, fp)
        if existing is not None and stage.name in targets:  # the caller reads it: check its bytes first
            store.check_inputs({stage.name: existing}, {stage.name: stage.command})
        if existing is None:
            lock = store.lock(stage.name, fp)
            if not _try(lock):
                log(f"stage {stage.name!r}: another fftool process is building it (fp {fp[:12]}…) - waiting")
            with lock:  # the other process may have built it meanwhile
                existing = None if stage.name in forced else _cached(store, stage, fp)
                if existing is None:
                    existing = _build(cfg, store, item, built, runtime or Runtime(), benchmark)
        built[stage.name] = existing
    return built


def _try(lock: Any) -> bool:
    """Take `lock` if it is free (then release it to the `with` that follows); False if it is held."""
    from filelock import Timeout

    try:
        lock.acquire(timeout=0)
    except Timeout:
        return False
    lock.release()
    return True


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
    with store.build(stage.name, fp, schema_version=stage.version, params=item.params, inputs=item.inputs) as ctx:
        stats = stage.build(cfg, inputs, ctx, runtime, benchmark)
        build_s = time.perf_counter() - started - checked_s
        ctx.stats = stats | {"input_check_seconds": round(checked_s, 4), "build_seconds": round(build_s, 3)}
    assert ctx.artifact is not None
    log(f"stage {stage.name!r}: wrote {ctx.artifact.path}")
    return ctx.artifact
