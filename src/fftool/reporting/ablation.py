"""The ablation: every (seed, benchmark, predictor) evaluation built through the DAG, then the paper's tables.

`run` asks the pipeline for one `evaluate` artifact per cell (a grid seed is one more parameter, set by
`config.seeded_config`, so each seed's models are cached like any other): whatever is missing upstream
(tracks, forces, the goal U-Net, goal samples, the CVAE of that variant) is built first and whatever exists
is reused. `write_report` scores every evaluation with its intervals (reporting/scores.py), renders Tables
II-VI and replaces the report folder atomically, and only a folder fftool may replace
(`check_report_folder`): new, empty, or a previous report (its marker file).
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import torch

from fftool import __version__, pipeline
from fftool.artifacts.store import ArtifactStore
from fftool.config import SEEDED_SECTIONS, PipelineConfig, predictor_config, seeded_config
from fftool.errors import UsageError
from fftool.outputs import replacing_folder
from fftool.reporting import claims, score_plots, scores, tables
from fftool.stages.evaluate import METRIC_DEFINITIONS, codes_of
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


def cells(cfg: PipelineConfig, benchmarks: Iterable[str], variants: Iterable[str]) -> list[Cell]:
    """Every seed × benchmark × predictor of the grid, in report order, with the configuration it runs."""
    return [
        Cell(seed, benchmark, predictor, predictor_config(cfg if seed is None else seeded_config(cfg, seed), predictor))
        for seed in grid_seeds(cfg)
        for benchmark in benchmarks
        for predictor in predictors(cfg, variants)
    ]


# Builds what the cells need ahead of `run`, e.g. concurrently (fftool.scheduler.build_grid); returns, per
# cell, the (stage, fingerprint) builds it was first to need and the seconds each took.
Prebuild = Callable[[list[tuple[PipelineConfig, str]]], list[dict[tuple[str, str], float]]]


def run(
    cfg: PipelineConfig,
    store: ArtifactStore,
    runtime: pipeline.Runtime,
    benchmarks: Iterable[str],
    variants: Iterable[str],
    on_cell: Callable[[str, str, int | None], None] | None = None,
    prebuild: Prebuild | None = None,
) -> list[dict[str, Any]]:
    """Build (or reuse) the evaluation of each seed × benchmark × predictor; their manifest stats with ids.

    Each cell's `built_now` lists the stages it was first to need that were not in the store, and its
    `cell_seconds` the time they took: with `prebuild` (parallel builds) their build times, else the cell's
    wall time.
    """
    grid = cells(cfg, benchmarks, variants)
    prebuilt = prebuild([(cell.cfg, cell.benchmark) for cell in grid]) if prebuild else None
    results = []
    for i, cell in enumerate(grid):
        if on_cell:
            on_cell(cell.benchmark, cell.predictor, cell.seed)
        started = time.perf_counter()
        built = pipeline.run(cell.cfg, store, ["evaluate"], runtime=runtime, benchmark=cell.benchmark)
        artifact = built["evaluate"]
        if prebuilt is None:
            new, took = list(built.new), time.perf_counter() - started
        else:
            new, took = [stage for stage, _ in prebuilt[i]], sum(prebuilt[i].values())
        results.append(
            artifact.manifest.stats
            | {
                "artifact": artifact.id,
                "grid_seed": cell.seed,
                "windows": built["windows"].id,
                "built_now": new,
                "cell_seconds": took,
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
    on_cell: Callable[[str, str, int | None], None] | None = None,
    prebuild: Prebuild | None = None,
) -> tuple[Path, list[dict[str, Any]], float]:
    """`fftool reproduce`: build or reuse every cell (`run`), then write the report with its figures into
    `out_dir` (checked by `check_report_folder`); the report's path, the cells' results and the minutes taken."""
    started = time.perf_counter()
    results = run(cfg, store, runtime, benchmarks, variants, on_cell=on_cell, prebuild=prebuild)
    draw = lambda folder: figures(cfg, store, results, folder)  # noqa: E731
    report = write_report(cfg, store, results, out_dir, profile, command, time.perf_counter() - started, draw)
    return report, results, (time.perf_counter() - started) / 60


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


def check_report_folder(out_dir: Path, artifact_root: Path, reports_dir: Path) -> Path:
    """`out_dir` resolved, if a report may replace it; UsageError otherwise (nothing is touched).

    Refused: the artifact root and anything inside it but `reports_dir`, the current and the home
    directory, any parent of those, a file, and a folder holding anything but a previous report.
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
    _check_replaceable(target, flag)
    return target


def _check_replaceable(target: Path, flag: str) -> None:
    """Only a folder that is new, empty, or a report whose marker lists every file in it may be replaced:
    anything a user added to a report folder is named and kept."""
    if target.is_symlink() or (target.exists() and not target.is_dir()):
        raise UsageError(f"{flag}: refused, it is a file or a link; give a folder")
    if not target.is_dir() or not any(target.iterdir()):
        return
    marker = target / REPORT_MARKER
    if not marker.is_file():
        raise UsageError(
            f"{flag}: refused, the folder holds files fftool did not write (no {REPORT_MARKER} marker); "
            "give a new or empty folder"
        )
    written = set(marker.read_text().splitlines()[1:])
    found = {path.relative_to(target).as_posix() for path in target.rglob("*") if not path.is_dir()}
    foreign = sorted(found - written - {REPORT_MARKER})
    if foreign:
        shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
        raise UsageError(
            f"{flag}: refused, the report folder holds files its report did not write ({shown}); "
            "move them out or give another folder"
        )


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
    """Tables II-VI (md, csv, tex), results.csv (one row per evaluation, its own intervals) and report.md; the
    old report is replaced only when complete. Every metric is recomputed from the saved predictions.

    `out_dir` must have passed `check_report_folder`; it is checked again here, just before the swap.
    """
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
    _check_replaceable(out_dir, f"report folder {out_dir}")
    with replacing_folder(out_dir) as partial:
        tables.write(built, partial, _preamble(command, seconds, results), _definitions())
        pd.DataFrame(rows).to_csv(partial / "results.csv", index=False)
        goal_module = goal_module_rows(cfg, store, results)
        if goal_module:
            pd.DataFrame(goal_module).to_csv(partial / "goal_fde.csv", index=False)
        title = f"{profile}: minFDE and NC per benchmark ({cfg.evaluate.protocol} protocol), {grid.level:.0%} intervals"
        drawn = [score_plots.scores_figure(grid, partial / "scores.png", title), *(draw(partial) if draw else [])]
        with (partial / "report.md").open("a") as report:
            report.writelines(f"\n![{path.stem}]({path.name})\n" for path in drawn)
        written = sorted(path.relative_to(partial).as_posix() for path in partial.rglob("*") if not path.is_dir())
        heading = f"written by fftool {__version__}; the next report replaces this folder and these files:"
        (partial / REPORT_MARKER).write_text("\n".join([heading, *written]) + "\n")
        _check_replaceable(out_dir, f"report folder {out_dir}")  # it may have changed during a long run
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
