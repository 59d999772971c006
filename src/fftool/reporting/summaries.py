"""Rich tables built from artifact manifests (summaries people would rather look at than read)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Final

import pandas as pd
from rich import box
from rich.table import Table

from fftool.artifacts.store import Artifact
from fftool.dataset.scenes import BENCHMARKS
from fftool.variants import reads_goal


def _benchmark_part_table(title: str, columns: tuple[str, ...], rows: list[tuple[str, str, list[str]]]) -> Table:
    """A table with benchmark and part columns, one section per benchmark."""
    table = Table(title=title, title_justify="left", box=box.SIMPLE_HEAD, caption_justify="left")
    table.add_column("benchmark", no_wrap=True)
    table.add_column("part", no_wrap=True)
    for name in columns:
        table.add_column(name, justify="right", no_wrap=True)
    previous = None
    for benchmark, part, cells in rows:
        if previous is not None and benchmark != previous:
            table.add_section()
        previous = benchmark
        table.add_row(benchmark, part, *cells)
    return table


def windows_summary_table(windows: Artifact) -> Table:
    """Per benchmark and part: windows, valid agent-windows, pedestrians and frames."""
    keys = ("windows", "agent_windows", "pedestrians", "frames", "candidate_windows")
    names = sorted({r["benchmark"] for r in windows.manifest.stats["summary"]})
    data = "ETH/UCY leave-one-out" if set(names) <= set(BENCHMARKS) else f"dataset {', '.join(names)}:"
    table = _benchmark_part_table(
        f"{data} windows ({windows.id})",
        ("windows", "valid agent-windows", "pedestrians", "frames", "candidates"),
        [(r["benchmark"], r["part"], [f"{r[k]:,}" for k in keys]) for r in windows.manifest.stats["summary"]],
    )
    table.caption = (
        "windows: start frames with ≥ 1 pedestrian present at all 20 steps;\n"
        "candidates: every start frame; pedestrians, frames: in the part's raw files"
    )
    return table


def artifacts_table(artifacts: list[Artifact]) -> Table:
    table = Table(title="artifacts", title_justify="left")
    for name in ("id", "about", "schema", "created", "files", "size", "inputs"):
        table.add_column(name, justify="right" if name in ("files", "size") else "left")
    for artifact in artifacts:
        manifest = artifact.manifest
        size = sum(f["bytes"] for f in manifest.files.values())
        raw = sum(1 for name in manifest.inputs if name.startswith("raw/"))
        inputs = ", ".join(f"{name}/{fp[:8]}" for name, fp in manifest.built_from().items()) or (
            f"{raw} raw files" if raw or not manifest.inputs else f"{len(manifest.inputs)} evaluations"  # a report
        )
        table.add_row(
            artifact.id,
            artifact.label,
            f"v{manifest.schema_version}",
            manifest.created_at,
            str(len(manifest.files)),
            f"{size / 1e6:.1f} MB",
            inputs,
        )
    if not artifacts:
        table.caption = "no artifacts yet: run `fftool ingest`"
    return table


def forces_summary_table(forces: Artifact) -> Table:
    """Per benchmark and part: mean |F_dr|, mean |F_re|, share of pairs removed as groups, time."""
    stats = forces.manifest.stats
    table = _benchmark_part_table(
        f"social forces ({forces.id})",
        ("agent-windows", "mean |F_dr| (m/s²)", "mean |F_re| (m/s²)", "pairs grouped", "compute (s)"),
        [
            (
                r["benchmark"],
                r["part"],
                [
                    f"{r['agent_windows']:,}",
                    f"{r['mean_abs_f_dr']:.3f}",
                    f"{r['mean_abs_f_re']:.3f}",
                    f"{r['grouped_pair_share']:.1%}",
                    f"{r['seconds']:.2f}",
                ],
            )
            for r in stats["summary"]
        ],
    )
    table.caption = (
        f"{stats['distinct_agent_windows']:,} distinct agent-windows computed in {stats['seconds_total']:.1f} s "
        f"(setup incl. DBSCAN {stats['seconds_setup']:.1f} s); means over agent-windows and all 20 steps;\n"
        "pairs grouped: ordered pairs of valid agents in one window that DBSCAN groups (no mutual repulsion); "
        "compute: time of the part's raw files (shared files are computed once)"
    )
    return table


def maps_table(maps: Artifact) -> Table:
    """Per scene: raster size, cell size, world extent, and where to look at it."""
    stats = maps.manifest.stats
    table = Table(title=f"scene maps ({maps.id})", title_justify="left", box=box.SIMPLE_HEAD)
    for name in ("scene", "cells (W × H)", "m/cell", "x range (m)", "y range (m)", "check figure"):
        table.add_column(name, no_wrap=True)
    for scene, t in stats["scenes"].items():
        x0, y0, r = t["origin_x_m"], t["origin_y_m"], t["resolution_m"]
        table.add_row(
            scene,
            f"{t['width']} × {t['height']}",
            f"{r:g}",
            f"{x0:.1f} … {x0 + t['width'] * r:.1f}",
            f"{y0:.1f} … {y0 + t['height'] * r:.1f}",
            str(maps.path / f"{scene}_check.png"),
        )
    for scene in stats["without_geometry"]:
        table.add_row(scene, "no geometry", "", "", "", "")
    table.caption = f"channels: {', '.join(stats['channels'])}"
    table.caption_justify = "left"
    return table


def training_table(artifact: Artifact, what: str) -> Table:
    """One row per epoch of a training: loss terms and validation metrics; the kept epoch in bold."""
    stats = artifact.manifest.stats
    table = Table(
        title=f"{what}, {stats['benchmark']} ({artifact.id}, {stats['device']})",
        title_justify="left",
        box=box.SIMPLE_HEAD,
    )
    rows = stats["log"]
    for name in rows[0] if rows else []:
        table.add_column(name, justify="right", no_wrap=True)
    for row in rows:
        best = row["epoch"] == stats["best_epoch"]
        table.add_row(
            *(f"{v:.4g}" if isinstance(v, float) else str(v) for v in row.values()), style="bold" if best else None
        )
    table.caption = f"best epoch {stats['best_epoch']} (bold) kept"
    table.caption_justify = "left"
    return table


def goal_fde_table(goals: dict[str, Artifact]) -> Table:
    """Test goal-FDE@K per benchmark beside the constant-velocity reference and the published anchors."""
    from fftool.dataset.scenes import PUBLISHED_GOAL_FDE20

    first = next(iter(goals.values())).manifest.stats
    k = first["k"]
    table = Table(title=f"goal module alone: test goal-FDE (m), K = {k}", title_justify="left", box=box.SIMPLE_HEAD)
    names = (f"ours @{k}", "ours @1 (mode)", f"CV @{k}", "CV @1", "Y-net @20", "Goal-SAR @20", "agent-windows")
    table.add_column("benchmark", no_wrap=True)
    for name in names:
        table.add_column(name, justify="right", no_wrap=True)
    values = []
    for benchmark, artifact in goals.items():
        test = artifact.manifest.stats["parts"]["test"]
        row = [test[f"goal_fde@{k}_m"], test["goal_fde@1_m"], test[f"cv_fde@{k}_m"], test["cv_fde@1_m"]]
        values.append(row)
        anchors = [PUBLISHED_GOAL_FDE20[name][benchmark] for name in ("Y-net", "Goal-SAR")]
        table.add_row(
            benchmark, *(f"{v:.3f}" for v in row), *(f"{v:.2f}" for v in anchors), f"{test['agent_windows']:,}"
        )
    if len(goals) == 5:
        means = [sum(col) / 5 for col in zip(*values)]
        table.add_section()
        table.add_row("average", *(f"{v:.3f}" for v in means), "0.27", "0.29", "")
    table.caption = (
        "FDE@K = min over the K goals of the distance to the true final position; CV: constant-velocity "
        f"extrapolation (@1) and {k} heading/speed perturbations of it; anchors: published goal-module FDE@20"
    )
    table.caption_justify = "left"
    return table


def evaluation_table(artifacts: list[Artifact]) -> Table:
    """One row per evaluation: predictor, protocol, minADE/minFDE, NC, size and speed."""
    table = Table(title="evaluation", title_justify="left", box=box.SIMPLE_HEAD, caption_justify="left")
    for name in ("benchmark", "predictor", "protocol", "K", "minADE (m)", "minFDE (m)", "NC", "agent-windows", "aw/s"):
        table.add_column(name, justify="left" if name in ("benchmark", "predictor", "protocol") else "right")
    for artifact in artifacts:
        s = artifact.manifest.stats
        table.add_row(
            s["benchmark"],
            s["variant"],
            s["protocol"],
            str(s["k"]),
            f"{s['min_ade']:.3f}",
            f"{s['min_fde']:.3f}",
            str(s["nc"]["best_ade"]["ordered"]),
            f"{s['agent_windows']:,}",
            f"{s['agent_windows_per_s']:.0f}",
        )
    if artifacts:
        s = artifacts[0].manifest.stats
        table.caption = (
            f"{s['part']} part; NC: ordered pairs-steps closer than {s['collision_threshold_m']} m, best-ADE samples "
            f"(paper); artifacts: {', '.join(a.id for a in artifacts)}"
        )
    return table


def rescore_table(evaluation: Artifact, rescored: dict) -> Table:
    """An evaluation's metrics as stored and as re-scored from its predictions at another collision threshold."""
    stored = evaluation.manifest.stats
    title = f"evaluation {evaluation.id} re-scored: {stored['benchmark']}, {stored['variant']}, K = {stored['k']}"
    table = Table(title=title, title_justify="left", box=box.SIMPLE_HEAD, caption_justify="left")
    names = ("", "γ (m)", "minADE (m)", "minFDE (m)", "NC", "NC unordered", "NC joint", "NC joint unordered")
    for name in (*names, "COL (%)", "Col-II"):
        table.add_column(name, justify="left" if not name else "right", no_wrap=True)
    for label, s in (("stored", stored), ("re-scored", rescored)):
        nc = [s["nc"][sample][pairs] for sample in ("best_ade", "joint") for pairs in ("ordered", "unordered")]
        col = [f"{s['col']:.2f}", str(s["col_gt"])] if "col" in s else ["-", "-"]  # evaluations built before COL
        table.add_row(
            label, f"{s['collision_threshold_m']:g}", f"{s['min_ade']:.3f}", f"{s['min_fde']:.3f}", *map(str, nc), *col
        )
    table.caption = (
        f"{stored['part']} part, {stored['agent_windows']:,} agent-windows, from the saved predictions (no sampling); "
        "NC: pairs-steps closer than γ, ordered unless noted, best-ADE samples (paper) or one joint sample per window; "
        "COL and Col-II use their own 0.2 m (docs/metrics.md)"
    )
    return table


# Each report table for a terminal: file stem, title, and the metric of columns that name only a scene.
_REPORT_TABLES: Final = (
    ("table2_ade_fde", "Table II", ""),
    ("table3_fde", "Table III, per variant", "minFDE"),
    ("table4_collisions", "Table IV", "NC"),
    ("table5_collision_metrics", "Table V", ""),
    ("table6_paired", "Table VI, variant minus AgentFormer (paired)", ""),
)
_UNITS: Final = {"minADE": "m", "minFDE": "m", "COL": "%", "JADE": "m", "JFDE": "m"}
_DERIVED: Final = (" sd", " low", " high", " per seed", " (paper)")
_TOTALS: Final = ("average", "sum", "all scenes")
_PUBLISHED: Final = ", published, not re-run"


def report_tables(report_dir: Path) -> list[Table]:
    """The report's Tables II-VI for a terminal, from their CSV files: one table per metric, the estimates
    only (the intervals are in the Markdown files), the paper's numbers in a dim row under each method that
    has them, and no column without a number, so a row fits one line of 100 columns."""
    tables = []
    for stem, title, bare in _REPORT_TABLES:
        frame = pd.read_csv(report_dir / f"{stem}.csv", keep_default_na=False)
        for metric, columns in _metric_columns(frame, bare).items():
            rows = frame if "metric" not in frame.columns else frame[frame["metric"] == metric]
            tables.append(_metric_table(f"{title}: {metric}", rows, columns, metric, f"{stem}.md"))
    return tables


def _metric_columns(frame: pd.DataFrame, bare: str) -> dict[str, list[str]]:
    """metric -> its estimate columns: "<scene> <metric>" columns grouped by metric, columns that name only a
    scene under `bare`, or under each of the rows' own metrics (Table VI)."""
    found: dict[str, list[str]] = {}
    scenes = [c for c in frame.columns[1:] if c != "metric" and not c.endswith(_DERIVED)]
    for column in scenes:
        scene, _, metric = column.partition(" ")
        own = column in _TOTALS or (scene in BENCHMARKS and not metric)
        for name in (frame["metric"].unique() if "metric" in frame.columns else [bare]) if own else [metric]:
            found.setdefault(str(name), []).append(column)
    return found


def _metric_table(title: str, rows: pd.DataFrame, columns: list[str], metric: str, intervals: str) -> Table:
    unit = _UNITS.get(metric.lstrip("Δ"))
    table = Table(title=f"{title} ({unit})" if unit else title, title_justify="left", box=box.SIMPLE_HEAD,
                  caption_justify="left")  # fmt: skip
    shown = [c for c in columns if pd.to_numeric(rows[c], errors="coerce").notna().any()]
    table.add_column("method", no_wrap=True)
    for column in shown:
        table.add_column(column.removesuffix(f" {metric}"), justify="right", no_wrap=True)
    position = ("minADE", "minFDE").index(metric) if metric in ("minADE", "minFDE") else 0
    dim = False
    for row in rows.to_dict("records"):
        name = str(row[rows.columns[0]])
        ours = [_number(row[c], metric) for c in shown]
        published = [_paper(row.get(f"{c.removesuffix(f' {metric}')} (paper)", ""), position) for c in shown]
        if any(ours):
            table.add_row(name, *ours)
        if any(published):
            table.add_row(name.removesuffix(_PUBLISHED) if not any(ours) else "  (paper)", *published, style="dim")
            dim = True
    table.caption = f"estimates{'; dim: published' if dim else ''}; intervals in {intervals}"
    return table


def _number(value: object, metric: str) -> str:
    number = pd.to_numeric(value, errors="coerce")
    if pd.isna(number):
        return ""
    sign = "+" if metric.startswith("Δ") else ""
    digits = 0 if metric.lstrip("Δ") in ("NC", "Col-II") else 2 if metric.lstrip("Δ") == "COL" else 3
    return f"{number:{sign}.{digits}f}"


def _paper(text: object, position: int) -> str:
    """One number of a published cell ("0.45/0.75": minADE/minFDE; "655": NC)."""
    parts = [part.strip() for part in str(text).split("/")] if text else []
    return parts[0] if len(parts) == 1 else parts[position] if position < len(parts) else ""


def run_summary(results: list[dict]) -> Table:
    """What a reproduce/ablate run did per cell: which stages it built, which it found, how long it took."""
    table = Table(title="run summary", title_justify="left", box=box.SIMPLE_HEAD, caption_justify="left")
    seeded = any(r["grid_seed"] is not None for r in results)
    for name in ("benchmark", "predictor", *(["seed"] if seeded else []), "protocol", "built now", "minutes"):
        table.add_column(name, justify="right" if name in ("seed", "minutes") else "left")
    table.add_column("evaluation")
    for r in results:
        built = ", ".join(r["built_now"]) or "[dim]nothing (all reused)[/]"
        minutes = f"{r['cell_seconds'] / 60:.1f}"
        seed = [str(r["grid_seed"])] if seeded else []
        table.add_row(r["benchmark"], r["variant"], *seed, r["protocol"], built, minutes, r["artifact"])
    return table


def _best_row(manifest: Any) -> dict[str, Any]:
    """The log row of a trained model's best epoch (its validation numbers)."""
    stats = manifest.stats
    rows = [row for row in stats.get("log", []) if row.get("epoch") == stats.get("best_epoch")]
    return rows[0] if rows else {}


def zoo_rows(models: list[Any]) -> list[dict[str, str]]:
    """One row per shipped model: name, kind, id, its validation numbers, best epoch / epochs, size. A model
    that reads a goal shows them under the fair protocol (sample k decodes the goal module's goal k), labelled
    "fair": chosen that way in training, or scored that way afterwards (`fftool models validate`); "true goals"
    labels numbers where each window's true end point was the goal, which no user has."""
    from fftool.zoo import fair_numbers

    rows = []
    for model in models:
        manifest = model.artifact.manifest
        row = _best_row(manifest)
        fair = any(k.startswith("val_fair_min_ade") for k in row)  # chosen under the fair protocol
        prefix = "val_fair_min_" if fair else "val_min_"
        ade = next((v for k, v in row.items() if k.startswith(f"{prefix}ade")), None)
        fde = next((v for k, v in row.items() if k.startswith(f"{prefix}fde")), None)
        scored = fair_numbers(model, models) if model.variant is not None and reads_goal(model.variant) else None
        mean = False
        if scored is not None:  # with the goal U-Net shipped beside it: preferred to the training's own
            ade, fde, fair, mean = scored["min_ade_m"], scored["min_fde_m"], True, scored.get("code") == "mean"
        if ade is not None and fde is not None:
            shown = f"minADE/FDE {ade:.3f}/{fde:.3f}"
            if model.variant is not None and reads_goal(model.variant):
                shown += (" (fair, mean code)" if mean else " (fair)") if fair else " (true goals)"
        else:
            best = next(
                ((k, v) for k, v in manifest.stats.items() if k.startswith("best_") and k != "best_epoch"), None
            )
            shown = f"{best[0].removeprefix('best_')} {best[1]:.3f}" if best and best[1] is not None else ""
        rows.append(
            {
                "name": model.name,
                "kind": model.kind,
                "id": model.artifact.id,
                "validation (best epoch)": shown,
                "epochs": f"{manifest.stats.get('best_epoch', '')}/{len(manifest.stats.get('log', []))}",
                "size": f"{sum(f['bytes'] for f in manifest.files.values()) / 1e6:.2f} MB",
            }
        )
    return rows


def zoo_caption(models: list[Any]) -> str:
    total = sum(sum(f["bytes"] for f in m.artifact.manifest.files.values()) for m in models)
    if not models:
        return "no shipped models"
    return (
        f"{len(models)} model(s), {total / 1e6:.1f} MB; orphaned: the code no longer computes its fingerprint; "
        "(fair): validated with the goal module's goals, sample k with goal k, as predictions are made "
        "(mean code: each goal decoded from the prior's mean, as the profile samples it); "
        "(true goals): validated with the true end point as the goal, which no prediction has "
        "(`fftool models validate` scores them under the fair protocol)"
    )


def zoo_table(models: list[Any], orphaned: set[str]) -> Table:
    """The shipped models (`zoo_rows`) with their status: current, or orphaned."""
    table = Table(title="shipped models (models/<profile>/)", title_justify="left")
    for name in ("name", "kind", "id", "validation (best epoch)", "epochs", "size", "status"):
        table.add_column(name, justify="right" if name in ("epochs", "size") else "left", no_wrap=name != "id")
    for model, row in zip(models, zoo_rows(models)):
        status = "[red]orphaned[/]" if model.name in orphaned else "[green]current[/]"
        table.add_row(*row.values(), status)
    table.caption = zoo_caption(models)
    return table
