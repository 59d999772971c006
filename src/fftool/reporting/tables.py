"""The paper's Tables II-IV from evaluation scores, with the published numbers beside ours, and two more:
the field's other collision metrics (V) and paired differences against the baseline (VI).

Input: `scores.Score`s per (benchmark, predictor, metric). Each table has a display frame (Markdown and
LaTeX: one compact cell per number, `estimate ±sd [low, high]`, the ± only with several seeds) and a data
frame (CSV: estimate, sd, interval bounds and the per-seed values in columns of their own). "Average" is the
mean of the evaluated scenes (Social-GAN convention), "Sum" their sum; both are left empty unless all five
scenes were evaluated, so a partial run never looks complete.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import pandas as pd

from fftool.dataset.scenes import BENCHMARKS
from fftool.paper import PAPER_NAMES, PUBLISHED_REFERENCES, TABLE2_ADE_FDE, TABLE3_FDE, TABLE4_COLLISIONS
from fftool.reporting.scores import MEANS, Score, combine
from fftool.variants import PREDICTORS

Scores = Mapping[tuple[str, str, str], Score]


@dataclass(frozen=True)
class Table:
    name: str  # file stem
    title: str
    frame: pd.DataFrame  # display cells (md, tex); first column: method
    caption: str
    data: pd.DataFrame  # numbers (csv): estimate, sd, low, high, per seed


# How a row names where its CVAE took its K codes (`Grid.method`).
CODE_NAMES: Final = {"prior": "CVAE samples", "dlow": "DLow", "mean": "mean code"}


@dataclass(frozen=True)
class Grid:
    """What the tables cover: scores, the scenes and predictors present, and the interval level."""

    scores: Scores
    level: float
    # where each CVAE takes its K futures' codes (`evaluate.codes_of`): "prior", "dlow", "mean"; absent: prior
    codes: Mapping[str, str] = field(default_factory=dict)

    def method(self, predictor: str) -> str:
        """A row's name, saying how a CVAE drew its samples when any CVAE of the grid draws other than from its
        prior: "AgentFormer (DLow)", "ForceFormer-Re (mean code)" against "ForceFormer-Dr (CVAE samples)" (the
        caption says so when none does)."""
        if predictor == "cv" or set(self.codes.values()) <= {"prior"}:
            return PAPER_NAMES[predictor]
        return f"{PAPER_NAMES[predictor]} ({CODE_NAMES[self.codes.get(predictor, 'prior')]})"

    @property
    def scenes(self) -> list[str]:
        present = {b for b, _, _ in self.scores}
        return [b for b in BENCHMARKS if b in present] + sorted(present - set(BENCHMARKS))  # then a dataset's

    @property
    def predictors(self) -> list[str]:
        present = {p for _, p, _ in self.scores}
        return [p for p in PREDICTORS if p in present]

    @property
    def complete(self) -> bool:
        return self.scenes == list(BENCHMARKS)

    def columns(self, total: str) -> list[str]:
        """The scenes, then the total column (Average or Sum)."""
        return [*self.scenes, total]

    def get(self, scene: str, predictor: str, metric: str, total: str) -> Score | None:
        """One scene's score, or the total over all five scenes (None when a scene is missing)."""
        if scene != total:
            return self.scores[(scene, predictor, metric)]
        if not self.complete:
            return None
        scenes = (self.scores[(s, predictor, metric)] for s in self.scenes)
        return combine(scenes, "mean" if total == "average" else "sum")


def _fmt(value: float | None, digits: int) -> str:
    return "" if value is None or pd.isna(value) else f"{value:.{digits}f}"


def cell(score: Score | None, digits: int, level: float, signed: bool = False) -> str:
    """The compact form: `0.216 ±0.004 [0.205, 0.228]` (± over seeds only when there are several)."""
    if score is None:
        return ""
    sign = "+" if signed else ""
    low, high = score.interval(level)
    spread = "" if math.isnan(score.sd) else f" ±{score.sd:.{digits}f}"
    return f"{score.estimate:{sign}.{digits}f}{spread} [{low:{sign}.{digits}f}, {high:{sign}.{digits}f}]"


def numbers(prefix: str, score: Score | None, level: float) -> dict[str, float | str]:
    """The CSV columns of one number: estimate, sd over seeds, interval bounds, the per-seed values."""
    if score is None:
        return {prefix: "", f"{prefix} sd": "", f"{prefix} low": "", f"{prefix} high": "", f"{prefix} per seed": ""}
    low, high = score.interval(level)
    per_seed = ";".join(f"{v:.6g}" for v in score.per_seed)
    return {prefix: score.estimate, f"{prefix} sd": score.sd, f"{prefix} low": low, f"{prefix} high": high,
            f"{prefix} per seed": per_seed}  # fmt: skip


def table2(grid: Grid, caption: str) -> Table:
    """minADE/minFDE per scene and their average, ours and the paper's side by side."""
    shown, data = [], []
    for predictor in grid.predictors:
        row: dict[str, str] = {"method": grid.method(predictor)}
        numeric: dict[str, float | str] = {"method": grid.method(predictor)}
        for scene in grid.columns("average"):
            ade, fde = (grid.get(scene, predictor, m, "average") for m in ("min_ade", "min_fde"))
            row[scene] = f"{cell(ade, 3, grid.level)} / {cell(fde, 3, grid.level)}" if ade is not None else ""
            numeric |= numbers(f"{scene} minADE", ade, grid.level) | numbers(f"{scene} minFDE", fde, grid.level)
            paper = TABLE2_ADE_FDE.get(predictor, {}).get(scene)
            row[f"{scene} (paper)"] = numeric[f"{scene} (paper)"] = f"{paper[0]:.2f}/{paper[1]:.2f}" if paper else ""
        shown.append(row)
        data.append(numeric)
    for method, published in PUBLISHED_REFERENCES.items():  # not re-run: their own papers' numbers only
        row = {"method": method} | {f"{s} (paper)": f"{published[s][0]:.2f}/{published[s][1]:.2f}"
                                    for s in grid.columns("average") if s in published}  # fmt: skip
        shown.append(row)
        data.append(dict(row))
    frames = pd.DataFrame(shown).fillna(""), pd.DataFrame(data)
    return Table("table2_ade_fde", "Table II: minADE / minFDE (m)", frames[0], caption, frames[1])


def _scalar_table(
    grid: Grid,
    metrics: Mapping[str, tuple[str, int]],  # metric -> (column label, digits)
    total: str,
    published: Mapping[str, Mapping[str, Mapping[str, float]]],  # metric -> the paper's numbers
    predictors: list[str] | None = None,
    score_of: Callable[[str, str, str], Score | None] | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """One cell per scene and metric, a total over all five scenes, and the paper's numbers beside ours."""
    shown, data = [], []
    get = score_of or (lambda scene, predictor, metric: grid.get(scene, predictor, metric, total))
    for predictor in predictors or grid.predictors:
        row: dict[str, str] = {"method": grid.method(predictor)}
        numeric: dict[str, float | str] = {"method": grid.method(predictor)}
        for scene in grid.columns(total):
            for metric, (label, digits) in metrics.items():
                name = f"{scene} {label}".rstrip()
                score = get(scene, predictor, metric)
                row[name] = cell(score, digits, grid.level, signed=score_of is not None)
                numeric |= numbers(name, score, grid.level)
                if metric in published:
                    paper = _fmt(published[metric].get(predictor, {}).get(scene), 2 if metric in MEANS else 0)
                    row[f"{name} (paper)"] = numeric[f"{name} (paper)"] = paper
        shown.append(row)
        data.append(numeric)
    return pd.DataFrame(shown), pd.DataFrame(data)


def table3(grid: Grid, caption: str) -> Table:
    """minFDE per variant (the ablation), ours and the paper's."""
    frames = _scalar_table(grid, {"min_fde": ("", 3)}, "average", {"min_fde": TABLE3_FDE})
    return Table("table3_fde", "Table III: minFDE (m) per variant", frames[0], caption, frames[1])


def table4(grid: Grid, caption: str, count_digits: int) -> Table:
    """Collision counts NC per variant and their sum, ours and the paper's."""
    frames = _scalar_table(grid, {"nc": ("", count_digits)}, "sum", {"nc": TABLE4_COLLISIONS})
    return Table("table4_collisions", "Table IV: number of collisions NC", frames[0], caption, frames[1])


def table5(grid: Grid, caption: str, count_digits: int) -> Table:
    """The field's other collision metrics beside NC, COL (% of samples) and Col-II (agent-windows), and the
    joint metrics JADE / JFDE (one sample index for a whole window; docs/metrics.md); no published ForceFormer
    numbers exist for them. COL, JADE and JFDE average over scenes, Col-II sums like NC."""
    metrics = {"col": ("COL", 2), "col_gt": ("Col-II", count_digits), "jade": ("JADE", 3), "jfde": ("JFDE", 3)}
    shown, data = [], []
    for metric, total in (("col", "average"), ("col_gt", "sum"), ("jade", "average"), ("jfde", "average")):
        frames = _scalar_table(grid, {metric: metrics[metric]}, total, {})
        shown.append(frames[0].set_index("method"))
        data.append(frames[1].set_index("method"))
    frame, numbers_ = (pd.concat(parts, axis=1).reset_index() for parts in (shown, data))
    title = (
        "Table V: COL (% of the K samples, EigenTrajectory), Col-II (agent-windows, Trajnet++) and the joint "
        "JADE / JFDE (m, Weng et al. 2023)"
    )
    return Table("table5_collision_metrics", title, frame, caption, numbers_)


PAIRED_METRICS: Final = {
    "min_ade": "minADE", "min_fde": "minFDE", "nc": "NC", "col": "COL", "col_gt": "Col-II", "jade": "JADE",
    "jfde": "JFDE",
}  # fmt: skip


def table6(grid: Grid, caption: str, reference: str = "baseline") -> Table:
    """Each ForceFormer variant minus the reference on the same windows and seeds (paired), per metric: a
    difference whose interval excludes 0 is one the test set supports. "all scenes" is the Average of the
    mean metrics and the Sum of the counts, as in Tables II-V."""
    variants = [p for p in grid.predictors if p not in (reference, "cv")]
    rows_shown, rows_data = [], []
    for metric, label in PAIRED_METRICS.items():
        total = "average" if metric in MEANS else "sum"

        def difference(scene: str, predictor: str, _metric: str, _total: str = total) -> Score | None:
            ours, theirs = grid.get(scene, predictor, _metric, _total), grid.get(scene, reference, _metric, _total)
            return None if ours is None or theirs is None else ours - theirs

        digits = 2 if metric == "col" else 3 if metric in MEANS else 1
        shown, data = _scalar_table(grid, {metric: ("", digits)}, total, {}, variants, difference)
        for frame, into in ((shown, rows_shown), (data, rows_data)):
            frame.insert(1, "metric", f"Δ{label}")
            into.append(frame.rename(columns=lambda c, t=total: c.replace(t, "all scenes", 1)))  # average or sum
    title = f"Table VI: paired differences, variant minus {grid.method(reference)} (same windows, same seeds)"
    return Table("table6_paired", title, pd.concat(rows_shown), caption, pd.concat(rows_data))


def markdown(table: Table) -> str:
    frame = table.frame.astype(str)
    header = "| " + " | ".join(frame.columns) + " |"
    rule = "|" + "|".join(":---" if i == 0 else "---:" for i in range(len(frame.columns))) + "|"
    body = ["| " + " | ".join(row) + " |" for row in frame.to_numpy().tolist()]
    return "\n".join([f"### {table.title}", "", header, rule, *body, "", f"_{table.caption}_", ""])


def latex(table: Table) -> str:
    frame = table.frame.map(lambda text: str(text).replace("±", r"$\pm$").replace("Δ", r"$\Delta$"))
    frame.columns = [c.replace("Δ", r"$\Delta$") for c in frame.columns]
    caption = f"{table.title}. {table.caption}".replace("%", r"\%").replace("±", r"$\pm$").replace("Δ", r"$\Delta$")
    return frame.to_latex(index=False, caption=caption, label=table.name)


def write(tables: list[Table], out_dir: Path, preamble: str, epilogue: str = "") -> Path:
    """Each table as .md, .csv (its numbers) and .tex, and report.md with all of them; returns report.md's path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for table in tables:
        (out_dir / f"{table.name}.md").write_text(markdown(table))
        table.data.to_csv(out_dir / f"{table.name}.csv", index=False)
        (out_dir / f"{table.name}.tex").write_text(latex(table))
    report = out_dir / "report.md"
    report.write_text(preamble + "\n" + "\n".join(markdown(t) for t in tables) + epilogue)
    return report
