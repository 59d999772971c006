"""The paper's Tables II-IV from evaluation results, with the published numbers beside ours.

Input: one row per (benchmark, predictor) evaluation (an `evaluate` manifest's stats). Output: pandas
frames written as Markdown, CSV and LaTeX, each with a caption naming protocol, K, γ, pair order,
profile and seeds. "Average" is the mean of the evaluated scenes (Social-GAN convention), "Sum" their
sum; both are left empty unless all five scenes were evaluated, so a partial run never looks complete.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from fftool.dataset.scenes import BENCHMARKS
from fftool.paper import PAPER_NAMES, PREDICTORS, TABLE2_ADE_FDE, TABLE3_FDE, TABLE4_COLLISIONS


@dataclass(frozen=True)
class Table:
    name: str  # file stem
    title: str
    frame: pd.DataFrame  # first column: method
    caption: str


def results_frame(results: Iterable[Mapping[str, Any]], pairs: str, sample: str) -> pd.DataFrame:
    """Long format: benchmark, predictor, protocol, min_ade, min_fde, nc, agent_windows, seconds."""
    rows = [
        {
            "benchmark": r["benchmark"],
            "predictor": r["variant"],
            "protocol": r["protocol"],
            "k": r["k"],
            "min_ade": r["min_ade"],
            "min_fde": r["min_fde"],
            "nc": r["nc"][sample][pairs],
            "agent_windows": r["agent_windows"],
            "seconds": r["seconds"],
        }
        for r in results
    ]
    frame = pd.DataFrame(rows)
    order = {name: i for i, name in enumerate(PREDICTORS)}
    return frame.sort_values(["predictor", "benchmark"], key=lambda c: c.map(order) if c.name == "predictor" else c)


def _scenes(results: pd.DataFrame) -> list[str]:
    present = set(results["benchmark"])
    return [b for b in BENCHMARKS if b in present]


def _complete(scenes: list[str]) -> bool:
    return scenes == list(BENCHMARKS)


def _fmt(value: float | None, digits: int = 2) -> str:
    return "" if value is None or pd.isna(value) else f"{value:.{digits}f}"


def table2(results: pd.DataFrame, caption: str) -> Table:
    """minADE/minFDE per scene and their average, ours and the paper's side by side."""
    scenes = _scenes(results)
    rows = []
    for predictor, group in results.groupby("predictor", sort=False):
        by = group.set_index("benchmark")
        row: dict[str, str] = {"method": PAPER_NAMES[predictor]}
        for scene in [*scenes, "average"]:
            if scene == "average":
                ade, fde = (by["min_ade"].mean(), by["min_fde"].mean()) if _complete(scenes) else (None, None)
            else:
                ade, fde = by.loc[scene, "min_ade"], by.loc[scene, "min_fde"]
            row[scene] = f"{_fmt(ade)}/{_fmt(fde)}" if ade is not None else ""
            paper = TABLE2_ADE_FDE.get(predictor, {}).get(scene)
            row[f"{scene} (paper)"] = f"{paper[0]:.2f}/{paper[1]:.2f}" if paper else ""
        rows.append(row)
    return Table("table2_ade_fde", "Table II: minADE / minFDE (m)", pd.DataFrame(rows), caption)


def _scalar_table(
    results: pd.DataFrame,
    column: str,
    total: tuple[str, Callable[[pd.Series], float]],
    fmt: Callable[[float | None], str],
    published: Mapping[str, Mapping[str, float]],
) -> pd.DataFrame:
    """One number per scene and a total over all five scenes, ours and the paper's side by side."""
    scenes = _scenes(results)
    total_name, aggregate = total
    rows = []
    for predictor, group in results.groupby("predictor", sort=False):
        by = group.set_index("benchmark")[column]
        row = {"method": PAPER_NAMES[predictor]}
        for scene in [*scenes, total_name]:
            if scene == total_name:
                row[scene] = fmt(aggregate(by) if _complete(scenes) else None)
            else:
                row[scene] = fmt(by[scene])
            row[f"{scene} (paper)"] = fmt(published.get(predictor, {}).get(scene))
        rows.append(row)
    return pd.DataFrame(rows)


def table3(results: pd.DataFrame, caption: str) -> Table:
    """minFDE per variant (the ablation), ours and the paper's."""
    frame = _scalar_table(results, "min_fde", ("average", pd.Series.mean), _fmt, TABLE3_FDE)
    return Table("table3_fde", "Table III: minFDE (m) per variant", frame, caption)


def table4(results: pd.DataFrame, caption: str) -> Table:
    """Collision counts per variant and their sum, ours and the paper's."""
    count = lambda value: "" if value is None else str(int(value))  # noqa: E731
    frame = _scalar_table(results, "nc", ("sum", pd.Series.sum), count, TABLE4_COLLISIONS)
    return Table("table4_collisions", "Table IV: number of collisions", frame, caption)


def markdown(table: Table) -> str:
    frame = table.frame.astype(str)
    header = "| " + " | ".join(frame.columns) + " |"
    rule = "|" + "|".join(":---" if i == 0 else "---:" for i in range(len(frame.columns))) + "|"
    body = ["| " + " | ".join(row) + " |" for row in frame.to_numpy().tolist()]
    return "\n".join([f"### {table.title}", "", header, rule, *body, "", f"_{table.caption}_", ""])


def latex(table: Table) -> str:
    return table.frame.to_latex(index=False, caption=f"{table.title}. {table.caption}", label=table.name)


def write(tables: list[Table], out_dir: Path, preamble: str) -> Path:
    """Each table as .md, .csv and .tex, and report.md with all of them; returns report.md's path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for table in tables:
        (out_dir / f"{table.name}.md").write_text(markdown(table))
        table.frame.to_csv(out_dir / f"{table.name}.csv", index=False)
        (out_dir / f"{table.name}.tex").write_text(latex(table))
    report = out_dir / "report.md"
    report.write_text(preamble + "\n" + "\n".join(markdown(t) for t in tables))
    return report
