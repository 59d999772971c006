"""The ablation: every (seed, benchmark, predictor) evaluation built through the DAG, then the paper's tables.

`run` hands the grid engine (fftool.scheduler) one `evaluate` build per cell (a grid seed is one more
parameter, set by `config.seeded_config`, so each seed's models are cached like any other): whatever is
missing upstream (tracks, forces, the goal U-Net, goal samples, the CVAE of that variant) is built first,
once however many cells need it, and whatever exists is reused. `build_report` makes the report an artifact
of the store (every evaluation scored with its intervals by reporting/scores.py, Tables II-VI, figures),
and `publish` copies it into the report folder, replaced whole and only where the output guard lets it
(`check_report_folder`): new, empty, or a previous report (its marker file).
"""

from __future__ import annotations

import os
import platform
import shutil
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import torch

from fftool import __version__, pipeline, scheduler
from fftool.artifacts.hashing import fingerprint
from fftool.artifacts.store import Artifact, ArtifactStore
from fftool.config import SEEDED_SECTIONS, PipelineConfig, predictor_config, seeded_config
from fftool.errors import IntegrityError, UsageError
from fftool.outputs import Kind, check_output, replacing_folder
from fftool.reporting import claims, score_plots, scores, tables
from fftool.stages.evaluate import METRIC_DEFINITIONS, codes_of
from fftool.ui import log
from fftool.variants import PREDICTORS


def predictors(cfg: PipelineConfig, variants: Iterable[str]) -> list[str]:
    """cv (if asked), then baseline (always), then the chosen variants, in the paper's order."""
    chosen = {"baseline", *variants} | ({"cv"} if cfg.report.constant_velocity else set())
    return [p for p in PREDICTORS if p in chosen]


def grid_seeds(cfg: PipelineConfig) -> list[int | None]:
    """The grid's seeds (report.seeds), or [None]: one run with each section's own seed."""
    return list(cfg.report.seeds) or [None]


@dataclass(frozen=True)
class Cell:
    """One evaluation of the grid: its seed (None: the sections' own), benchmark, predictor and configuration."""

    seed: int | None
    benchmark: str
    predictor: str
    cfg: PipelineConfig

    @property
    def name(self) -> str:
        return f"{self.benchmark} / {self.predictor}" + ("" if self.seed is None else f" / seed {self.seed}")


def cells(cfg: PipelineConfig, benchmarks: Iterable[str], variants: Iterable[str]) -> list[Cell]:
    """Every seed × benchmark × predictor of the grid, in report order, with the configuration it runs."""
    return [
        Cell(seed, benchmark, predictor, predictor_config(cfg if seed is None else seeded_config(cfg, seed), predictor))
        for seed in grid_seeds(cfg)
        for benchmark in benchmarks
        for predictor in predictors(cfg, variants)
    ]


@dataclass(frozen=True)
class Workers:
    """Where the grid's stage builds run (scheduler.build_grid): this process (jobs 1), local workers, or
    the Dask cluster at `address`; torch threads per build (None: shared out, or torch's own with one job)."""

    jobs: int = 1
    threads: int | None = None
    address: str | None = None


def run(
    cfg: PipelineConfig,
    store: ArtifactStore,
    runtime: pipeline.Runtime,
    benchmarks: Iterable[str],
    variants: Iterable[str],
    workers: Workers = Workers(),
) -> list[dict[str, Any]]:
    """Build (or reuse) the evaluation of each seed × benchmark × predictor through the grid engine; their
    manifest stats with ids. Each cell's `built_now` lists the stages it was first to need that were not in
    the store, and its `cell_seconds` the time they took."""
    grid = cells(cfg, benchmarks, variants)
    built_now = scheduler.build_grid(
        [(cell.cfg, cell.benchmark) for cell in grid], store, runtime.device, workers.jobs, workers.threads,
        workers.address, names=[cell.name for cell in grid],
    )  # fmt: skip
    results = []
    for cell, new in zip(grid, built_now):
        built = pipeline.run(cell.cfg, store, ["evaluate"], runtime=runtime, upstream=False, benchmark=cell.benchmark)
        artifact = built["evaluate"]
        results.append(
            artifact.manifest.stats
            | {
                "artifact": artifact.id,
                "grid_seed": cell.seed,
                "windows": built["windows"].id,
                "built_now": [stage for stage, _ in new],
                "cell_seconds": sum(new.values()),
            }
        )
    return results


def reproduce(
    cfg: PipelineConfig,
    store: ArtifactStore,
    runtime: pipeline.Runtime,
    benchmarks: Iterable[str],
    variants: Iterable[str],
    out_dir: Path,
    profile: str,
    command: str,
    workers: Workers = Workers(),
) -> tuple[Path, list[dict[str, Any]], float]:
    """`fftool reproduce`: build or reuse every cell (`run`), then the report (an artifact of the store, reused
    when nothing it reads changed), published into `out_dir` (checked by `check_report_folder`); the report's
    path, the cells' results and the minutes taken."""
    started = time.perf_counter()
    results = run(cfg, store, runtime, benchmarks, variants, workers)
    report = build_report(cfg, store, results, profile, command, started)
    publish(report, out_dir, "--out")
    return out_dir / "report.md", results, (time.perf_counter() - started) / 60


def figures(cfg: PipelineConfig, store: ArtifactStore, results: list[dict[str, Any]], out_dir: Path) -> list[Path]:
    """A report's figures: the density curves of every predictor, the qualitative panels of all but cv; of the
    first grid seed only."""
    from fftool.reporting import plots

    results = [r for r in results if r["grid_seed"] == results[0]["grid_seed"]]
    windows_ids = {r["windows"] for r in results}
    if len(windows_ids) != 1:
        raise ValueError(f"the evaluations come from {len(windows_ids)} different windows artifacts")
    evaluations: dict[str, list[plots.Evaluation]] = {}
    for r in results:
        evaluations.setdefault(r["benchmark"], []).append(plots.Evaluation.of(store.resolve(r["artifact"])))
    windows = store.resolve(windows_ids.pop())
    resampling = plots.resampling_of(cfg.report, cfg.windows)
    return plots.figures(
        evaluations, windows, cfg.evaluate.part, Path(cfg.data.scenes_dir), out_dir, density_only=("cv",),
        resampling=resampling,
    )  # fmt: skip


def caption(cfg: PipelineConfig, profile: str) -> str:
    report, ev = cfg.report, cfg.evaluate
    return (
        f"Ours: profile {profile}; goal protocol {ev.protocol!r} for goal, dr, re (baseline and cv read no goal); "
        f"{_samplers(cfg)}; "
        f"K = {ev.k} samples; test part of each leave-one-out benchmark; NC at gamma = {ev.collision_threshold_m} m "
        f"over {report.collision_pairs} pairs of {report.collision_sample.replace('_', '-')} samples; {_seeds(cfg)}; "
        f"[low, high]: {report.confidence:.0%} percentile interval of a moving-block bootstrap over test windows "
        f"(blocks of {report.block_length(cfg.windows)} consecutive windows, {report.bootstrap_resamples} resamples, "
        f"seed {report.bootstrap_seed}). "
        "Paper: ForceFormer Tables II-IV (its goal protocol = ours 'paper')."
    )


def _codes(cfg: PipelineConfig) -> dict[str, str]:
    """Where each CVAE of the report takes its K futures' codes (`evaluate.codes_of`)."""
    return {p: codes_of(predictor_config(cfg, p)) for p in ("baseline", *cfg.report.variants)}


def _samplers(cfg: PipelineConfig) -> str:
    codes = _codes(cfg)
    if set(codes.values()) == {"prior"}:
        return "every CVAE's K samples drawn from its prior (no DLow)"
    named = {"dlow": "a DLow sampler", "mean": "the prior's mean code for each of the K goals"}
    parts = [f"{text} for {', '.join(p for p, c in codes.items() if c == code)}" for code, text in named.items()
             if code in codes.values()]  # fmt: skip
    return f"K futures from {'; from '.join(parts)}; from the CVAE's prior for the others"


def _seeds(cfg: PipelineConfig) -> str:
    if cfg.report.seeds:
        seeds = ", ".join(map(str, cfg.report.seeds))
        return f"mean ±sd over grid seeds {seeds} (each sets the {', '.join(SEEDED_SECTIONS)} seeds)"
    return f"seeds: cvae {cfg.cvae.seed}, goal {cfg.goal.seed}, goals {cfg.goals.seed}, evaluate {cfg.evaluate.seed}"


REPORT_MARKER = ".fftool-report"  # marks a folder as a report fftool wrote and may replace


def _foreign(folder: Path) -> str | None:
    """What a report folder holds that its report did not write: a folder without the marker, or files the
    marker does not list (anything a user added is named and kept)."""
    marker = folder / REPORT_MARKER
    if not marker.is_file():
        return f"refused, the folder holds files fftool did not write (no {REPORT_MARKER} marker)"
    written = set(marker.read_text().splitlines()[1:])
    found = {path.relative_to(folder).as_posix() for path in folder.rglob("*") if not path.is_dir()}
    foreign = sorted(found - written - {REPORT_MARKER})
    if not foreign:
        return None
    shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
    return f"refused, the report folder holds files its report did not write ({shown})"


REPORT_FOLDER = Kind("a report folder", True, _foreign)


def check_report_folder(out_dir: Path, artifact_root: Path, reports_dir: Path) -> Path:
    """`out_dir` resolved, if a report may replace it; UsageError otherwise (nothing is touched).

    Refused: the artifact root and anything inside it but `reports_dir`, the current and the home
    directory, any parent of those, and what the output guard refuses (a file, a link, a folder holding
    anything but a previous report).
    """
    target, root = out_dir.expanduser().resolve(), artifact_root.resolve()
    flag = f"--out {out_dir}"
    for what, protected in (
        ("the artifact root", root),
        ("the current directory", Path.cwd()),
        ("your home", Path.home()),
    ):
        if protected.resolve().is_relative_to(target):
            raise UsageError(f"{flag}: refused, it is {what} or holds it; give a folder of its own for the report")
    if target.is_relative_to(root) and not target.is_relative_to(reports_dir.resolve()):
        raise UsageError(f"{flag}: refused, it lies inside the artifact root {root}; reports go under {reports_dir}")
    check_output(out_dir.expanduser(), "--out", REPORT_FOLDER)
    return target


REPORT_KIND, REPORT_VERSION = "report", 1  # the report's artifact in the store


def build_report(
    cfg: PipelineConfig,
    store: ArtifactStore,
    results: list[dict[str, Any]],
    profile: str,
    command: str,
    started: float,
) -> Artifact:
    """The report of these evaluations as an artifact of the store (written atomically, like a stage's), or
    the one already there: its fingerprint is the evaluations', the configuration's, the profile's name and
    the command's, so a re-run that changes none of them renders nothing."""
    params = {"profile": profile, "command": command, "config": cfg.model_dump(mode="json")}
    inputs = {_cell_name(r): store.resolve(r["artifact"]).fingerprint for r in results}
    fp = fingerprint(REPORT_KIND, REPORT_VERSION, params, inputs)
    found = store.lookup(REPORT_KIND, fp)
    if found is not None:
        problems = store.verify(found)
        if problems:  # never published as if it were the report these evaluations make
            raise IntegrityError(
                f"report {found.id} ({found.path}) changed since it was built: {problems[0]}; nothing was "
                "published. Remove that folder (fftool's own; the next run rebuilds it) and run again"
            )
        log(f"report {found.id} is cached - publishing it")
        return found
    with store.build(REPORT_KIND, fp, schema_version=REPORT_VERSION, params=params, inputs=inputs) as ctx:
        draw = lambda folder: figures(cfg, store, results, folder)  # noqa: E731
        write_report(cfg, store, results, ctx.dir, profile, command, time.perf_counter() - started, draw)
        ctx.stats = {"cells": len(results)}
    assert ctx.artifact is not None
    return ctx.artifact


def publish(report: Artifact, out_dir: Path, flag: str) -> None:
    """Copy a report artifact's files into `out_dir`, replaced whole and only if the output guard lets it
    (checked again just before the swap: a long run may have let a user add files), with a marker listing them."""
    check_output(out_dir, flag, REPORT_FOLDER)
    with replacing_folder(out_dir) as partial:
        for name in sorted(report.manifest.files):
            (partial / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(report.path / name, partial / name)
        heading = (
            f"written by fftool {__version__} from {report.id}; the next report replaces this folder, these files:"
        )
        (partial / REPORT_MARKER).write_text("\n".join([heading, *sorted(report.manifest.files)]) + "\n")
        check_output(out_dir, flag, REPORT_FOLDER)


def write_report(
    cfg: PipelineConfig,
    store: ArtifactStore,
    results: list[dict[str, Any]],
    out_dir: Path,
    profile: str,
    command: str,
    seconds: float,
    draw: Callable[[Path], list[Path]] | None = None,
) -> Path:
    """Tables II-VI (md, csv, tex), results.csv (one row per evaluation, its own intervals), the figures and
    report.md into `out_dir` (a build folder: `build_report` makes it an artifact). Every metric is recomputed
    from the saved predictions."""
    block = cfg.report.block_length(cfg.windows)
    scored, rows = scores.score(store, results, cfg.report, cfg.evaluate.collision_threshold_m, block)
    grid, text = tables.Grid(scored, cfg.report.confidence, _codes(cfg)), caption(cfg, profile)
    counts = 1 if len(grid_seeds(cfg)) > 1 else 0  # a mean over seeds of counts has a decimal
    built = [
        tables.table2(grid, text),
        tables.table3(grid, text),
        tables.table4(grid, text, counts),
        tables.table5(grid, text, counts),
        tables.table6(grid, text),
    ]
    claimed = claims.claims_table(grid, cfg.evaluate.protocol)  # all five benchmarks only
    built += [claimed] if claimed is not None else []
    tables.write(built, out_dir, _preamble(command, seconds, results), _definitions())
    pd.DataFrame(rows).to_csv(out_dir / "results.csv", index=False)
    goal_module = goal_module_rows(cfg, store, results)
    if goal_module:
        pd.DataFrame(goal_module).to_csv(out_dir / "goal_fde.csv", index=False)
    title = f"{profile}: minFDE and NC per benchmark ({cfg.evaluate.protocol} protocol), {grid.level:.0%} intervals"
    drawn = [score_plots.scores_figure(grid, out_dir / "scores.png", title), *(draw(out_dir) if draw else [])]
    with (out_dir / "report.md").open("a") as report:
        report.writelines(f"\n![{path.stem}]({path.name})\n" for path in drawn)
    return out_dir / "report.md"


def goal_module_rows(cfg: PipelineConfig, store: ArtifactStore, results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The goal module alone, per benchmark whose goal variants the report holds: goal-FDE@K and FDE@1 of its
    sampled goals and of constant velocity on the val and test parts (the goals artifact's manifest). Only for
    a grid of one seed: each grid seed has goal modules of its own."""
    if grid_seeds(cfg) != [None]:
        return []
    rows = []
    for benchmark in dict.fromkeys(r["benchmark"] for r in results if r.get("protocol") not in (None, "none")):
        artifact = pipeline.run(cfg, store, ["goals"], benchmark=benchmark, upstream=False)["goals"]
        k, parts = int(artifact.manifest.stats["k"]), artifact.manifest.stats["parts"]
        row: dict[str, Any] = {"benchmark": benchmark, "k": k, "goals": artifact.id}
        for part in ("val", "test"):
            stats = parts.get(part, {})
            row |= {
                f"{part}_goal_fde@k": stats.get(f"goal_fde@{k}_m"),
                f"{part}_goal_fde@1": stats.get("goal_fde@1_m"),
                f"{part}_cv_fde@k": stats.get(f"cv_fde@{k}_m"),
                f"{part}_cv_fde@1": stats.get("cv_fde@1_m"),
                f"{part}_agent_windows": stats.get("agent_windows"),
            }
        rows.append(row)
    return rows


def _preamble(command: str, seconds: float, results: list[dict[str, Any]]) -> str:
    devices = sorted({r["device"] for r in results})
    return "\n".join(
        [
            "# fftool report",
            "",
            f"- command: `{command}`",
            f"- finished: {time.strftime('%Y-%m-%d %H:%M %Z')}; wall time of this run: {seconds / 60:.1f} min "
            "(artifacts reused from the store cost nothing)",
            f"- machine: {platform.platform()}, {os.cpu_count()} CPU cores, torch {torch.__version__} with "
            f"{torch.get_num_threads()} threads, device {', '.join(devices)}",
            "- evaluations: " + ", ".join(f"{_cell_name(r)} = {r['artifact']}" for r in results),
            "",
        ]
    )


def _cell_name(result: dict[str, Any]) -> str:
    seed = "" if result["grid_seed"] is None else f"/seed {result['grid_seed']}"
    return f"{result['benchmark']}/{result['variant']}{seed}"


def _definitions() -> str:
    """The metric definitions, as every new evaluation manifest records them (older ones lack COL and Col-II)."""
    return "\n### Metric definitions\n\n" + "".join(f"- `{k}`: {v}\n" for k, v in METRIC_DEFINITIONS.items())
