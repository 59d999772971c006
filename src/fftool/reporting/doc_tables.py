"""Markdown tables for the docs, rendered from the committed CSVs a command wrote, never typed by hand.

The docs call these from cog blocks (`python -m cogapp -r <page>`); the test suite runs cog in check mode,
so a page that disagrees with the data it was rendered from fails.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

import pandas as pd

from fftool.dataset.scenes import BENCHMARKS, PUBLISHED_GOAL_FDE20
from fftool.paper import PAPER_NAMES, PUBLISHED_REFERENCES, TABLE2_ADE_FDE, TABLE3_FDE
from fftool.variants import PREDICTORS, reads_goal

_PROTOCOL_NAMES = {"fair": "fair", "paper": "paper's pick", "oracle": "true goal"}
_GOAL_MODULES = ("Y-net", "Goal-SAR")


def _markdown(header: Sequence[str], rows: Iterable[Sequence[str]], numeric_from: int = 1) -> str:
    align = [":---" if i < numeric_from else "---:" for i in range(len(header))]
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(align) + " |"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def _pair(ade: float, fde: float, digits: int = 3) -> str:
    return f"{ade:.{digits}f} / {fde:.{digits}f}"


def _predictor_rows(results_csvs: Sequence[Path | str]) -> tuple[list[str], Iterator[tuple[str, pd.DataFrame]]]:
    """The benchmarks the results cover, and (row name, its rows indexed by benchmark) per predictor and goal
    protocol, in the files' order and the paper's predictor order, each (predictor, protocol) once."""
    frames = [pd.read_csv(path) for path in results_csvs]
    benchmarks = [b for b in BENCHMARKS if any((frame["benchmark"] == b).any() for frame in frames)]
    if not benchmarks:  # a dataset of the user's own: its benchmarks as the files name them
        benchmarks = list(dict.fromkeys(b for frame in frames for b in frame["benchmark"]))
    frames = [frame[frame["benchmark"].isin(benchmarks)] for frame in frames]

    def rows() -> Iterator[tuple[str, pd.DataFrame]]:
        seen = set()
        for frame in frames:
            for variant in PREDICTORS:
                part = frame[frame["variant"] == variant].set_index("benchmark")
                protocol = str(part["protocol"].iloc[0]) if len(part) else ""
                if part.empty or (variant, protocol) in seen:
                    continue
                seen.add((variant, protocol))
                name = PAPER_NAMES[variant]
                yield (f"{name} ({_PROTOCOL_NAMES[protocol]})" if protocol in _PROTOCOL_NAMES else name), part

    return benchmarks, rows()


def protocol_table(*results_csvs: Path | str, published: bool = True) -> str:
    """minADE / minFDE per benchmark and, over all five, their average: one row per predictor and goal protocol
    from `fftool reproduce` results.csv files (in the order given), then the paper's and the published peers'."""
    benchmarks, predictors = _predictor_rows(results_csvs)
    columns = [*benchmarks, *(["average"] if len(benchmarks) == len(BENCHMARKS) else [])]
    rows = []
    for name, part in predictors:
        cells = [_pair(part.at[b, "min_ade"], part.at[b, "min_fde"]) if b in part.index else "" for b in benchmarks]
        if "average" in columns:
            full = len(part) == len(benchmarks)
            cells.append(_pair(part["min_ade"].mean(), part["min_fde"].mean()) if full else "")
        rows.append([name, *cells])
    if published:
        for variant in ("baseline", "goal", "dr", "re"):
            pick = " (paper's pick)" if reads_goal(variant) else ""
            if variant in TABLE2_ADE_FDE:
                cells = [_pair(*TABLE2_ADE_FDE[variant][c], digits=2) for c in columns]
            else:  # Table II omits Goal: its minFDE is in Table III
                cells = [f"– / {TABLE3_FDE[variant][c]:.2f}" for c in columns]
            rows.append([f"{PAPER_NAMES[variant]}, the paper{pick}", *cells])
        for name, pairs in PUBLISHED_REFERENCES.items():
            label = name.replace(", published, not re-run", ", published")
            rows.append([label, *(_pair(*pairs[c], digits=2) for c in columns)])
    return _markdown(["method", *columns], rows)


def benchmark_table(results_csv: Path | str) -> str:
    """One benchmark's minADE / minFDE and NC with their bootstrap intervals, one row per predictor and goal
    protocol, from a `fftool reproduce` results.csv of that benchmark alone."""
    benchmarks, predictors = _predictor_rows([results_csv])
    (benchmark,) = benchmarks

    def interval(row: pd.Series, column: str, digits: int) -> str:
        return f"{row[column]:.{digits}f} [{row[column + ' low']:.{digits}f}, {row[column + ' high']:.{digits}f}]"

    rows = []
    for name, part in predictors:
        row = part.loc[benchmark]
        rows.append([name, f"{interval(row, 'min_ade', 3)} / {interval(row, 'min_fde', 3)}", interval(row, "nc", 0)])
    return _markdown(["method", "minADE / minFDE (m)", "NC"], rows)


def collisions_table(*results_csvs: Path | str) -> str:
    """Collisions (NC) per benchmark and in total, one row per predictor and goal protocol."""
    benchmarks, predictors = _predictor_rows(results_csvs)
    rows = []
    for name, part in predictors:
        counts = [f"{part.at[b, 'nc']:.0f}" if b in part.index else "" for b in benchmarks]
        rows.append([name, *counts, f"{part['nc'].sum():.0f}"])
    return _markdown(["method", *benchmarks, "total"], rows)


def claims_table(claims_csv: Path | str) -> str:
    """The paper's claims as `fftool reproduce` judged them (claims.csv): claim, our number, outcome."""
    frame = pd.read_csv(claims_csv)
    rows = [[str(r.claim), str(r.ours), f"**{r.outcome}**"] for r in frame.itertuples()]
    return _markdown(["claim (the paper's)", "ours", "outcome"], rows, numeric_from=3)


def goal_fde_table(goal_fde_csv: Path | str) -> str:
    """The goal module alone (a report's goal_fde.csv): validation and test goal-FDE@K, FDE@1 of the mode,
    constant velocity's, and the published goal modules' FDE@20, per benchmark and averaged (also without eth,
    whose anchors come from another data file: docs/goal.md)."""
    frame = pd.read_csv(goal_fde_csv).set_index("benchmark")
    k = int(frame["k"].iloc[0])
    measured = ["val_goal_fde@k", "test_goal_fde@k", "test_goal_fde@1", "test_cv_fde@k", "test_cv_fde@1"]
    header = ["benchmark", f"val @{k}", f"test @{k}", "test @1 (mode)", f"test CV @{k}", "test CV @1",
              *(f"{name} @20" for name in _GOAL_MODULES), "test agent-windows"]  # fmt: skip
    rows = []
    for benchmark in [b for b in BENCHMARKS if b in frame.index]:
        r = frame.loc[benchmark]
        anchors = [f"{PUBLISHED_GOAL_FDE20[name][benchmark]:.2f}" for name in _GOAL_MODULES]
        rows.append([benchmark, *(f"{r[c]:.3f}" for c in measured), *anchors, f"{int(r['test_agent_windows']):,}"])
    if len(rows) == len(BENCHMARKS):
        for label, chosen in (("average", BENCHMARKS), ("average without eth", BENCHMARKS[1:])):
            means = frame.loc[list(chosen), measured].mean()
            anchors = [sum(PUBLISHED_GOAL_FDE20[name][b] for b in chosen) / len(chosen) for name in _GOAL_MODULES]
            rows.append([f"**{label}**", *(f"{means[c]:.3f}" for c in measured), *(f"{a:.3f}" for a in anchors), ""])
    return _markdown(header, rows)


def averages_table(fair_csv: Path | str, paper_csv: Path | str) -> str:
    """The front page's table: each predictor's five-benchmark average minADE / minFDE under the fair protocol
    and under the paper's pick, beside the paper's own number and the published peers'."""
    columns = {}
    for protocol, path in (("fair", fair_csv), ("paper", paper_csv)):
        frame = pd.read_csv(path)
        frame = frame[frame["benchmark"].isin(BENCHMARKS)]
        means = frame.groupby("variant")[["min_ade", "min_fde"]].mean()
        complete = frame.groupby("variant")["benchmark"].nunique() == len(BENCHMARKS)
        columns[protocol] = {v: _pair(*means.loc[v]) for v in means.index if complete[v]}
    rows = []
    for variant in PREDICTORS:
        if variant not in columns["fair"]:
            continue
        paper = TABLE2_ADE_FDE.get(variant, {}).get("average")
        published = (
            _pair(*paper, digits=2)
            if paper
            else (f"– / {TABLE3_FDE[variant]['average']:.2f}" if variant in TABLE3_FDE else "")
        )
        pick = columns["paper"].get(variant, "") if reads_goal(variant) else "same"
        rows.append([PAPER_NAMES[variant], f"**{columns['fair'][variant]}**", pick, published])
    for name, pairs in PUBLISHED_REFERENCES.items():
        rows.append(
            [name.replace(", published, not re-run", ", published"), _pair(*pairs["average"], digits=2), "", ""]
        )
    return _markdown(["method (five-benchmark average, m)", "fair", "paper's pick", "the paper"], rows)


def zoo_table(profile: str) -> str:
    """The shipped models of a profile as `fftool models list` shows them (without the status column)."""
    from fftool import zoo
    from fftool.reporting.summaries import zoo_caption, zoo_rows

    models = zoo.shipped(profile)
    rows = [[value for key, value in row.items() if key != "id"] for row in zoo_rows(models)]
    header = ["name", "kind", "validation (best epoch), metres", "best epoch / epochs", "size"]
    return _markdown(header, rows, numeric_from=3) + f"\n{zoo_caption(models)}.\n"


_MODE_NAMES = {0: "argmax", 1: "3 × 3 cells", 2: "5 × 5 cells"}


def levers_table(
    levers_csv: Path | str,
    radius: int | Sequence[int],
    names: dict[str, str],
    benchmarks: Sequence[str] = BENCHMARKS,
) -> str:
    """Validation goal-FDE@20 / FDE@1 per benchmark and their average for each lever of `names` (lever ->
    label, in that order) with the mode refined over `radius` cells, from benchmarks/goal_levers.py's CSV.
    Several radii give each lever one row per mode, named in a column of their own."""
    radii = [radius] if isinstance(radius, int) else list(radius)
    frame = pd.read_csv(levers_csv).drop_duplicates(["lever", "benchmark", "mode_radius_cells"], keep="last")
    rows = []
    for lever, label in names.items():
        for r in radii:
            part = frame[(frame["lever"] == lever) & (frame["mode_radius_cells"] == r)].set_index("benchmark")
            part = part[part.index.isin(benchmarks)]
            cells = [_pair(part.at[b, "val_goal_fde@20_m"], part.at[b, "val_goal_fde@1_m"]) if b in part.index else ""
                     for b in benchmarks]  # fmt: skip
            full = len(part) == len(benchmarks)
            mean = _pair(part["val_goal_fde@20_m"].mean(), part["val_goal_fde@1_m"].mean()) if full else ""
            rows.append([label, *([_MODE_NAMES[r]] if len(radii) > 1 else []), *cells, f"**{mean}**" if mean else ""])
    modes = ["mode"] if len(radii) > 1 else []
    return _markdown(["lever (validation goal-FDE@20 / FDE@1, m)", *modes, *benchmarks, "average"], rows,
                     numeric_from=1 + len(modes))  # fmt: skip


_LEVER_CODES = (("prior", "prior draws"), ("mean", "prior mean"))  # fair_validation.py's --code, as the tables name it


def output_lever_table(
    lever_csv: Path | str, codes_csv: Path | str, variant: str, shipped: str, shipped_sampling: str
) -> str:
    """A goal variant retrained with `cvae.output = "goal_residual"` (`benchmarks/fair_validation.py` rows with a
    `code` column) against its shipped model under one sampling (`benchmarks/fair_codes.py` rows): fair validation
    minADE / minFDE per benchmark and their average, one row per model and code."""
    lever, codes = pd.read_csv(lever_csv), pd.read_csv(codes_csv)
    runs = [(shipped, shipped_sampling, codes[(codes.variant == variant) & (codes.sampling == shipped_sampling)])]
    runs += [("goal_residual", sampling, lever[lever.code == code]) for code, sampling in _LEVER_CODES]
    rows = []
    for name, sampling, frame in runs:
        by = frame.set_index("benchmark")
        cells = [_pair(by.fair_min_ade_m[b], by.fair_min_fde_m[b]) for b in BENCHMARKS]
        average = _pair(by.fair_min_ade_m.mean(), by.fair_min_fde_m.mean(), digits=4)
        rows.append([name, sampling, *cells, f"**{average}**"])
    return _markdown([variant, "codes", *BENCHMARKS, "average"], rows, numeric_from=2)


def lever_average(levers_csv: Path | str, lever: str, radius: int) -> float:
    """A lever's five-benchmark average validation goal-FDE@20 (m) with the mode over `radius` cells, for prose."""
    frame = pd.read_csv(levers_csv)
    rows = frame[(frame["lever"] == lever) & (frame["mode_radius_cells"] == radius)]
    rows = rows.drop_duplicates("benchmark", keep="last").set_index("benchmark")
    return float(rows.loc[list(BENCHMARKS), "val_goal_fde@20_m"].mean())


def seeded_lever_fde(
    levers_csv: Path | str, arm: str, seeds: Sequence[int], benchmarks: Sequence[str], suffix: str, radius: int = 0
) -> pd.DataFrame:
    """goal-FDE@20 (m) of lever `arm` trained from each seed: one row per seed, one column per benchmark (rows
    `<arm>_s<seed><suffix>` of benchmarks/goal_levers.py's CSV, mode over `radius` cells); a missing run is NaN."""
    frame = pd.read_csv(levers_csv)
    frame = frame[frame["mode_radius_cells"] == radius].drop_duplicates(["lever", "benchmark"], keep="last")
    values = frame.set_index(["lever", "benchmark"])["val_goal_fde@20_m"]
    return pd.DataFrame(
        [[values.get((f"{arm}_s{seed}{suffix}", b), float("nan")) for b in benchmarks] for seed in seeds],
        index=pd.Index(list(seeds), name="seed"),
        columns=list(benchmarks),
    )


def seeded_lever_gap(lever: pd.DataFrame, reference: pd.DataFrame) -> tuple[float, float]:
    """The lever's mean over seeds of the benchmarks' average goal-FDE@20 minus the reference's (m), and the
    standard error of that difference, √(s²_lever / n_lever + s²_reference / n_reference)."""
    a, b = lever.mean(axis=1), reference.mean(axis=1)
    return float(a.mean() - b.mean()), float((a.var() / len(a) + b.var() / len(b)) ** 0.5)


def seeded_levers_table(
    levers_csv: Path | str,
    arms: dict[str, str],
    seeds: Sequence[int],
    benchmarks: Sequence[str],
    suffix: str = " best_epoch=val_part",
    radius: int = 0,
) -> str:
    """Each arm of `arms` (name -> label, the first the reference) trained from every seed: per benchmark the
    mean ± sample deviation of goal-FDE@20 over the seeds, each seed's benchmark average, their mean ± deviation,
    and the difference from the reference's mean with twice its standard error (`seeded_lever_gap`)."""
    runs = {arm: seeded_lever_fde(levers_csv, arm, seeds, benchmarks, suffix, radius) for arm in arms}
    first = next(iter(arms))
    rows = []
    for arm, label in arms.items():
        fde = runs[arm]
        per_seed = fde.mean(axis=1)
        gap, se = seeded_lever_gap(fde, runs[first])
        rows.append([
            label,
            *(f"{fde[b].mean():.3f} ± {fde[b].std():.3f}" for b in benchmarks),
            " / ".join(f"{v:.3f}" for v in per_seed),
            f"**{per_seed.mean():.4f} ± {per_seed.std():.4f}**",
            "" if arm == first else f"{gap:+.4f} ± {2 * se:.4f}",
        ])  # fmt: skip
    seeds_text = ", ".join(str(s) for s in seeds)
    header = ["arm (held-out goal-FDE@20, m)", *benchmarks, f"average, seeds {seeds_text}", "mean ± deviation",
              "against the first row ± 2 SE"]  # fmt: skip
    return _markdown(header, rows)


def _hedge_rows(hedge_csv: Path | str, variant: str, pick: str, code: str) -> pd.DataFrame:
    """benchmarks/goal_hedge.py's rows of `variant`, `pick` and `code` with the goal module's goals, the last of each
    (cell, goal-module seed, m)."""
    frame = pd.read_csv(hedge_csv)
    chosen = (frame["variant"] == variant) & (frame["pick"] == pick) & (frame["code"] == code)
    frame = frame[chosen & (frame["goals"] == "module")]
    return frame.drop_duplicates(["benchmark", "place", "goal_seed", "m"], keep="last")


def _per_cell(rows: pd.DataFrame, arm: str = "m") -> pd.DataFrame:
    """minADE and minFDE per (arm, benchmark, place), each the mean over the goal-module seeds."""
    return rows.groupby([arm, "benchmark", "place"])[["min_ade_m", "min_fde_m"]].mean()


def _screen_means(rows: pd.DataFrame, cells: Sequence[tuple[str, str]], arm: str = "m") -> pd.DataFrame:
    """minADE and minFDE per (arm, goal-module seed), each the mean over `cells`; an (arm, seed) short of a cell is
    dropped."""
    rows = rows[rows[["benchmark", "place"]].apply(tuple, axis=1).isin(cells)]
    grouped = rows.groupby([arm, "goal_seed"])
    means = grouped[["min_ade_m", "min_fde_m"]].mean()
    return means[grouped.size() == len(cells)]


def hedge_screen(
    hedge_csv: Path | str, variant: str, cells: Sequence[tuple[str, str]], pick: str = "first", code: str = "mean"
) -> pd.DataFrame:
    """minADE and minFDE per (m, goal-module seed) of `variant` decoding with `code`, hedged by `pick`, each the
    mean over the screen's (benchmark, place) cells; a (m, seed) missing a cell is dropped."""
    return _screen_means(_hedge_rows(hedge_csv, variant, pick, code), cells)


def _paired_change(change: pd.DataFrame) -> dict[str, tuple[float, float]]:
    """Per metric, the mean of the per-seed changes and twice its standard error (NaN from one seed)."""
    return {c: (change[c].mean(), 2 * change[c].std() / len(change) ** 0.5) for c in ("min_ade_m", "min_fde_m")}


def _paired_gaps(change: pd.DataFrame) -> list[str]:
    """The mean of each metric's per-seed change, with twice its standard error (none from one seed)."""
    return [
        f"{mean:+.4f}" + (f" ± {se2:.4f}" if len(change) > 1 else "") for mean, se2 in _paired_change(change).values()
    ]


def code_table(hedge_csv: Path | str, cells: Sequence[tuple[str, str]], arms: dict[tuple[str, str], str]) -> str:
    """Each (variant, code) arm of `arms` (-> label) at m = 0: per cell minADE / minFDE averaged over the goal-module
    seeds, the cells' mean, and its paired difference from the same variant with the mean code."""
    rows = []
    for (variant, code), label in arms.items():
        found = _hedge_rows(hedge_csv, variant, "first", code)
        per_cell, screen = _per_cell(found).loc[0], _screen_means(found, cells).loc[0]
        gaps = ["", ""] if code == "mean" else _paired_gaps(screen - hedge_screen(hedge_csv, variant, cells).loc[0])
        cell_text = [_pair(*per_cell.loc[cell]) for cell in cells]
        rows.append([label, *cell_text, f"**{_pair(*screen.mean(), digits=4)}**", *gaps])
    header = ["variant, code", *(f"{b}, {p} held out" for b, p in cells), "screen mean",
              "minADE vs mean code ± 2 SE", "minFDE vs mean code ± 2 SE"]  # fmt: skip
    return _markdown(header, rows)


def hedge_choice(
    hedge_csv: Path | str, variant: str, cells: Sequence[tuple[str, str]], pick: str, grid: Sequence[int], bar: float
) -> dict[str, float | int | bool]:
    """docs/experiments/goal-hedge.md's rule: m* in `grid` minimises the screen's mean minADE + minFDE; kept when
    m* > 0 lowers both against m = 0 by more than `bar` (m) and by more than twice their standard error."""
    screen = hedge_screen(hedge_csv, variant, cells, pick)
    best = int(screen.groupby(level="m").mean().loc[list(grid)].sum(axis=1).idxmin())
    (ade, ade_2se), (fde, fde_2se) = _paired_change(screen.loc[best] - screen.loc[0]).values()
    kept = best > 0 and all(gain > bar and gain > se2 for gain, se2 in ((-ade, ade_2se), (-fde, fde_2se)))
    return {"m": best, "ade_gain": -ade, "ade_2se": ade_2se, "fde_gain": -fde, "fde_2se": fde_2se, "kept": kept}


def agentformer_goals_table(hedge_csv: Path | str, cells: Sequence[tuple[str, str]], variants: Sequence[str]) -> str:
    """AgentFormer alone, then each variant decoding the end points of AgentFormer's K samples as its K goals
    (benchmarks/goal_hedge.py --goals agentformer): minADE / minFDE per cell, the cells' mean and its difference
    from AgentFormer alone."""
    frame = pd.read_csv(hedge_csv)
    frame = frame[(frame["goals"] == "agentformer") & (frame["pick"] == "first")]
    frame = frame.drop_duplicates(["benchmark", "place", "variant", "m"], keep="last").set_index(["benchmark", "place"])
    arms = {"AgentFormer alone": frame[frame["m"] > 0].groupby(level=[0, 1]).first()}
    arms |= {
        f"{v}, AgentFormer's end points as goals": frame[(frame["variant"] == v) & (frame["m"] == 0)] for v in variants
    }
    reference = arms["AgentFormer alone"].loc[list(cells), ["min_ade_m", "min_fde_m"]].mean()
    rows = []
    for label, rows_of in arms.items():
        values = rows_of.loc[list(cells), ["min_ade_m", "min_fde_m"]]
        change = values.mean() - reference
        gap = "" if label == "AgentFormer alone" else f"{change['min_ade_m']:+.4f} / {change['min_fde_m']:+.4f}"
        cell_text = [_pair(*values.loc[cell]) for cell in cells]
        rows.append([label, *cell_text, f"**{_pair(*values.mean(), digits=4)}**", gap])
    header = ["predictor", *(f"{b}, {p} held out" for b, p in cells), "mean", "vs AgentFormer alone"]
    return _markdown(header, rows)


def hedge_table(
    hedge_csv: Path | str,
    variant: str,
    cells: Sequence[tuple[str, str]],
    pick: str = "first",
    column: str = "{benchmark}, {place} held out",
) -> str:
    """Per m (K − m samples of `variant`, m of AgentFormer's DLow chosen by `pick`): each screen cell's minADE /
    minFDE averaged over the goal-module seeds, the cells' mean, and its paired difference from m = 0 with twice
    the standard error over the seeds (none from one seed). `column` names a cell's column."""
    found = _hedge_rows(hedge_csv, variant, pick, "mean")
    per_cell, screen = _per_cell(found), _screen_means(found, cells)
    reference = screen.loc[0]
    rows = []
    for m, by_seed in screen.groupby(level="m"):
        gaps = _paired_gaps(by_seed.droplevel("m") - reference) if m else ["", ""]
        cell_text = [_pair(*per_cell.loc[(m, b, p)]) for b, p in cells]
        rows.append([f"{m}", *cell_text, f"**{_pair(*by_seed.mean(), digits=4)}**", *gaps])
    header = ["m", *(column.format(benchmark=b, place=p) for b, p in cells), "screen mean",
              "minADE vs m = 0 ± 2 SE", "minFDE vs m = 0 ± 2 SE"]  # fmt: skip
    return _markdown(header, rows)


def _path_rows(curves_csv: Path | str) -> pd.DataFrame:
    """benchmarks/goal_curve_shapes.py's rows, the last of each (cell, goal-module seed, curve)."""
    return pd.read_csv(curves_csv).drop_duplicates(["benchmark", "place", "goal_seed", "curve"], keep="last")


def path_screen(curves_csv: Path | str, cells: Sequence[tuple[str, str]]) -> pd.DataFrame:
    """minADE and minFDE per (curve, goal-module seed), each the mean over the screen's `cells`."""
    return _screen_means(_path_rows(curves_csv), cells, "curve")


def path_choice(curves_csv: Path | str, cells: Sequence[tuple[str, str]], bar: float) -> dict[str, float | str | bool]:
    """docs/experiments/goal-paths.md's rule: the relaxation path with the lowest screen mean minADE, kept when it
    lowers it against the constant-acceleration curve by more than `bar` (m) and by more than twice its standard
    error over the goal-module seeds."""
    screen = path_screen(curves_csv, cells)
    means = screen.groupby(level="curve")["min_ade_m"].mean()
    best = str(means[means.index.str.startswith("relaxation")].idxmin())
    gain, se2 = _paired_change(screen.loc["acceleration"] - screen.loc[best])["min_ade_m"]
    return {"curve": best, "ade_gain": gain, "ade_2se": se2, "kept": bool(gain > bar and gain > se2)}


def path_table(curves_csv: Path | str, cells: Sequence[tuple[str, str]], val_parts: Sequence[str]) -> str:
    """Each curve's minADE per screen cell (the mean over the goal-module seeds), the cells' mean and its paired
    change from the constant-acceleration curve (± 2 SE over the seeds), then each benchmark's whole val part
    with the shipped goal module."""
    rows = _path_rows(curves_csv)
    per_cell, screen = _per_cell(rows, "curve"), _screen_means(rows, cells, "curve")
    reference = screen.loc["acceleration"]
    whole = rows[rows["place"] == "val part"].set_index(["curve", "benchmark"])["min_ade_m"]
    lines = []
    for curve in rows["curve"].unique():
        by_seed = screen.loc[curve]
        change = "" if curve == "acceleration" else _paired_gaps(by_seed - reference)[0]
        cells_text = [f"{per_cell.loc[(curve, b, p), 'min_ade_m']:.3f}" for b, p in cells]
        parts = [f"{whole.loc[(curve, b)]:.3f}" for b in val_parts]
        lines.append([curve, *cells_text, f"**{by_seed['min_ade_m'].mean():.4f}**", change, *parts])
    header = ["path (minADE, m)", *(f"{b}, {p} held out" for b, p in cells), "screen mean",
              "vs acceleration ± 2 SE", *(f"{b} val part" for b in val_parts)]  # fmt: skip
    return _markdown(header, lines)


def arms_validation_table(arms_csv: Path | str, reference: str) -> str:
    """Fair validation minADE / minFDE per benchmark of each arm (`benchmarks/fair_validation.py` rows with an `arm`
    column, in the file's order), the five-benchmark average where an arm has all five, and its change from
    `reference`'s average."""
    frame = pd.read_csv(arms_csv).drop_duplicates(["arm", "benchmark"], keep="last")
    averages = frame.groupby("arm")[["fair_min_ade_m", "fair_min_fde_m"]].mean()
    rows = []
    for arm, found in frame.groupby("arm", sort=False):
        by = found.set_index("benchmark")
        cells = [_pair(by.fair_min_ade_m[b], by.fair_min_fde_m[b]) if b in by.index else "" for b in BENCHMARKS]
        complete = by.index.isin(BENCHMARKS).sum() == len(BENCHMARKS)
        average = f"**{_pair(*averages.loc[arm], digits=4)}**" if complete else ""
        change = averages.loc[arm] - averages.loc[reference]
        gap = f"{change.iloc[0]:+.4f} / {change.iloc[1]:+.4f}" if complete and arm != reference else ""
        rows.append([arm, *cells, average, gap])
    return _markdown(["arm", *BENCHMARKS, "average", f"vs {reference}"], rows)


def _settled_below(paired: pd.DataFrame, variant: str, metric: str) -> bool:
    """Whether the report's paired bootstrap puts the whole all-scenes interval of variant − AgentFormer below 0."""
    rows = paired[paired["method"].str.startswith(PAPER_NAMES[variant]) & (paired["metric"] == metric)]
    return bool(len(rows) == 1 and rows["all scenes high"].iloc[0] < 0)


def targets_table(goal_fde_csv: Path | str, fair_results_csv: Path | str) -> str:
    """The goal-module and fair-protocol targets fftool works toward, each with the measured test number and
    whether it is met. A target against AgentFormer is met only when the paired bootstrap of the same report
    (its table6_paired.csv) settles it; ahead on the point estimates alone reads "ahead, not settled"."""
    goals = pd.read_csv(goal_fde_csv).set_index("benchmark")
    four = goals.loc[[b for b in BENCHMARKS if b != "eth"], "test_goal_fde@k"].mean()
    frame = pd.read_csv(fair_results_csv)
    paired = pd.read_csv(Path(fair_results_csv).with_name("table6_paired.csv"))
    means = frame[frame["benchmark"].isin(BENCHMARKS)].groupby("variant")[["min_ade", "min_fde", "nc"]]
    ade_fde, collisions = means.mean(), means.sum()["nc"]
    base = ade_fde.loc["baseline"]
    variants = [v for v in ("goal", "dr", "re") if v in ade_fde.index]
    best = min(variants, key=lambda v: (ade_fde.loc[v, "min_ade"], ade_fde.loc[v, "min_fde"]))
    met = lambda ok: "**met**" if ok else "not met"  # noqa: E731

    def against_agentformer(ahead: bool, settled: bool) -> str:
        return "**met**" if settled else "ahead, not settled" if ahead else "not met"

    rows = [
        ["goal module, test goal-FDE@20, average of hotel, univ, zara1, zara2", "≤ 0.26 m", f"{four:.3f} m",
         met(four <= 0.26)],
        ["goal module, test goal-FDE@20, eth", "≤ 0.60 m", f"{goals.at['eth', 'test_goal_fde@k']:.3f} m",
         met(goals.at["eth", "test_goal_fde@k"] <= 0.60)],
    ]  # fmt: skip
    for v in variants:
        ours = ade_fde.loc[v]
        ahead = ours["min_ade"] < base["min_ade"] and ours["min_fde"] < base["min_fde"]
        settled = _settled_below(paired, v, "ΔminADE") and _settled_below(paired, v, "ΔminFDE")
        rows.append([f"fair, five-benchmark average: {PAPER_NAMES[v]} below AgentFormer on minADE and minFDE, settled",
                     f"< {_pair(base['min_ade'], base['min_fde'])}", _pair(ours["min_ade"], ours["min_fde"]),
                     against_agentformer(ahead, settled)])  # fmt: skip
    rows.append([f"fair, the best variant ({PAPER_NAMES[best]}) at SingularTrajectory's level", "≤ 0.21 / 0.32",
                 _pair(ade_fde.loc[best, "min_ade"], ade_fde.loc[best, "min_fde"]),
                 met(ade_fde.loc[best, "min_ade"] <= 0.21 and ade_fde.loc[best, "min_fde"] <= 0.32)])  # fmt: skip
    if "re" in collisions.index:
        rows.append(["fair: ForceFormer-Re collides less than AgentFormer (NC, all scenes), settled",
                     f"< {collisions['baseline']:.0f}", f"{collisions['re']:.0f}",
                     against_agentformer(collisions["re"] < collisions["baseline"],
                                         _settled_below(paired, "re", "ΔNC"))])  # fmt: skip
    return _markdown(["target", "bar", "measured (test)", ""], rows, numeric_from=1)


def gap_table(results_csv: Path | str) -> str:
    """Each goal variant minus AgentFormer, minADE / minFDE in metres (negative: the variant is ahead), per
    benchmark and on the five-benchmark average, from one `fftool reproduce` results.csv."""
    frame = pd.read_csv(results_csv)
    frame = frame[frame["benchmark"].isin(BENCHMARKS)].set_index(["variant", "benchmark"])[["min_ade", "min_fde"]]
    benchmarks = [b for b in BENCHMARKS if b in frame.index.get_level_values("benchmark")]
    signed = lambda gap: f"{gap['min_ade']:+.3f} / {gap['min_fde']:+.3f}"  # noqa: E731
    rows = []
    for variant in (v for v in PREDICTORS if reads_goal(v) and v in frame.index.get_level_values("variant")):
        gap = frame.loc[variant].loc[benchmarks] - frame.loc["baseline"].loc[benchmarks]
        ahead = [b for b in benchmarks if (gap.loc[b] < 0).all()]
        rows.append([PAPER_NAMES[variant], *(signed(gap.loc[b]) for b in benchmarks), f"**{signed(gap.mean())}**",
                     ", ".join(ahead) or "none"])  # fmt: skip
    return _markdown(["variant − AgentFormer (m)", *benchmarks, "average", "ahead on both"], rows)


def _trained(results_csv: Path | str, benchmark: str) -> pd.DataFrame:
    """A results.csv's rows of one benchmark's trained predictors (constant velocity aside)."""
    frame = pd.read_csv(results_csv)
    return frame[(frame["benchmark"] == benchmark) & (frame["variant"] != "cv")]


def _trained_rows(results_csv: Path | str, benchmark: str) -> pd.DataFrame:
    """`_trained` by variant, in `PREDICTORS` order."""
    frame = _trained(results_csv, benchmark).set_index("variant")
    return frame.loc[[v for v in PREDICTORS if v in frame.index]]


def _retrain_change(shipped_csv: Path | str, retrained_csv: Path | str, benchmark: str) -> tuple[pd.DataFrame, ...]:
    """One benchmark's trained predictors, shipped and retrained (results.csv rows by variant, the variants both
    have), and retrained − shipped of minADE, minFDE and NC."""
    shipped, retrained = _trained_rows(shipped_csv, benchmark), _trained_rows(retrained_csv, benchmark)
    shipped, retrained = shipped.loc[shipped.index.isin(retrained.index)], retrained.loc[shipped.index]
    columns = ["min_ade", "min_fde", "nc"]
    return shipped, retrained, retrained[columns] - shipped[columns]


def largest_retrain_change(pairs: Sequence[tuple[Path | str, Path | str]], benchmark: str) -> tuple[float, int]:
    """The largest |change| of minADE or minFDE (m) and of NC between shipped and retrained results.csv pairs."""
    largest = pd.concat([_retrain_change(*pair, benchmark)[2].abs().max() for pair in pairs], axis=1).max(axis=1)
    return float(max(largest["min_ade"], largest["min_fde"])), int(largest["nc"])


def retrain_spread_table(shipped_csv: Path | str, retrained_csv: Path | str, benchmark: str) -> str:
    """A benchmark's test minADE / minFDE and NC from the shipped models and from the same recipe trained again
    (two `fftool reproduce` results.csv), per predictor that trains, and the change."""
    shipped, retrained, change = _retrain_change(shipped_csv, retrained_csv, benchmark)

    def cell(row: pd.Series, sign: str = "") -> str:
        return f"{row.min_ade:{sign}.3f} / {row.min_fde:{sign}.3f} ({row.nc:{sign}.0f})"

    rows = [
        [PAPER_NAMES[v], cell(shipped.loc[v]), cell(retrained.loc[v]), cell(change.loc[v], "+")] for v in change.index
    ]
    return _markdown(["predictor", "shipped: minADE / minFDE (NC)", "trained again", "change"], rows)


def _seed_rows(results_csv: Path | str, benchmark: str) -> pd.DataFrame:
    """`_trained` of a `reproduce --seeds` results.csv, by (variant, grid seed)."""
    return _trained(results_csv, benchmark).set_index(["variant", "grid_seed"]).sort_index()


def _spread(runs: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    by_variant = runs[["min_ade", "min_fde", "nc"]].groupby(level="variant")
    return by_variant.mean(), by_variant.std()


def seed_spread(results_csv: Path | str, benchmark: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The mean and the (sample) standard deviation over the seeds of each predictor's minADE, minFDE and NC."""
    return _spread(_seed_rows(results_csv, benchmark))


def seed_gaps(results_csv: Path | str, benchmark: str) -> dict[str, pd.DataFrame]:
    """Each goal variant minus AgentFormer trained with the same seed: minADE, minFDE and NC by seed."""
    frame = _seed_rows(results_csv, benchmark)[["min_ade", "min_fde", "nc"]]
    variants = frame.index.get_level_values("variant")
    return {v: frame.loc[v] - frame.loc["baseline"] for v in PREDICTORS if reads_goal(v) and v in variants}


def seed_table(results_csv: Path | str, benchmark: str) -> str:
    """A benchmark's test minADE / minFDE (NC) per predictor and training seed, and the mean ± sd over the seeds."""
    frame = _seed_rows(results_csv, benchmark)
    mean, sd = _spread(frame)
    seeds = sorted(frame.index.get_level_values("grid_seed").unique())
    rows = []
    for variant in (v for v in PREDICTORS if v in mean.index):
        runs, m, s = frame.loc[variant], mean.loc[variant], sd.loc[variant]
        cells = [f"{_pair(runs.min_ade[seed], runs.min_fde[seed])} ({runs.nc[seed]:.0f})" for seed in seeds]
        spread = f"{m.min_ade:.3f} ± {s.min_ade:.3f} / {m.min_fde:.3f} ± {s.min_fde:.3f} ({m.nc:.0f} ± {s.nc:.0f})"
        rows.append([PAPER_NAMES[variant], *cells, spread])
    header = ["minADE / minFDE (NC)", *(f"seed {int(seed)}" for seed in seeds), "mean ± sd"]
    return _markdown(header, rows)


def seed_gap_table(results_csv: Path | str, benchmark: str) -> str:
    """`seed_gaps` per seed, minADE / minFDE (m) and NC, and on how many seeds each variant is ahead on each
    (negative: ahead)."""
    gaps, rows = seed_gaps(results_csv, benchmark), []
    for variant, gap in gaps.items():
        cells = [f"{g.min_ade:+.3f} / {g.min_fde:+.3f} ({g.nc:+.0f})" for g in gap.itertuples()]
        ahead = (gap < 0).sum()
        counts = f"minADE {ahead.min_ade}; minFDE {ahead.min_fde}; NC {ahead.nc} of {len(gap)}"
        rows.append([PAPER_NAMES[variant], *cells, counts])
    seeds = next(iter(gaps.values())).index
    return _markdown(["variant − AgentFormer", *(f"seed {int(seed)}" for seed in seeds), "seeds ahead"], rows)


def _thread_minutes(stage_times: Path | str | pd.DataFrame) -> pd.DataFrame:
    """Stage × benchmark thread-minutes (build seconds × torch threads × ranks) of a `tools/stage_times.py --csv`
    file or its frame."""
    frame = (
        stage_times.copy() if isinstance(stage_times, pd.DataFrame) else pd.read_csv(stage_times, keep_default_na=False)
    )
    frame["minutes"] = frame["seconds"] * frame["threads"] * frame["ranks"] / 60
    return frame.pivot_table(index="stage", columns="benchmark", values="minutes", aggfunc="sum")


def training_times_table(stage_times: Path | str | pd.DataFrame, jobs: int = 2) -> str:
    """Thread-minutes per trained stage and benchmark (build seconds × torch threads × ranks, from a
    `tools/stage_times.py --csv` file or its frame), their sums, and the wall time an ideal `jobs`-way
    schedule of one-thread builds would need per benchmark (the sum over `jobs`, or the longest build if that
    is larger)."""
    table = _thread_minutes(stage_times)
    benchmarks = [b for b in BENCHMARKS if b in table.columns]
    cell = lambda value: "" if pd.isna(value) else f"{value:.1f}"  # noqa: E731
    rows = [[stage, *(cell(table.at[stage, b]) for b in benchmarks), cell(table.loc[stage].sum())]
            for stage in table.index]  # fmt: skip
    sums = table[benchmarks].sum()
    wall = [max(sums[b] / jobs, table[b].max()) for b in benchmarks]
    rows.append(["**sum (thread-minutes)**", *(f"**{sums[b]:.1f}**" for b in benchmarks), f"**{sums.sum():.1f}**"])
    rows.append([f"{jobs}-job wall, ideal (min)", *(f"{w:.1f}" for w in wall), f"{sum(wall):.1f}"])
    return _markdown(["stage", *benchmarks, "all"], rows)


def retrain_table(as_paid: Path | str, retrained: Path | str, benchmark: str, jobs: int = 2) -> str:
    """One benchmark's trained stages in thread-minutes, as the shipped models paid for them and as one run of
    today's code retrained them (two `tools/stage_times.py --csv` files; the stages the first lists), and what
    the retrained run's per-stage ratios make of the whole as-paid profile: an estimate, not a timing run."""
    paid = _thread_minutes(as_paid)
    now = _thread_minutes(retrained)[benchmark].dropna().loc[lambda stages: stages.index.isin(paid.index)]
    whole_paid = paid.loc[now.index].sum(axis=1)
    whole_now = whole_paid * now / paid[benchmark].loc[now.index]  # each stage at its retrained ratio
    rows = [[stage, f"{paid.at[stage, benchmark]:.1f}", f"{now[stage]:.1f}", f"{whole_paid[stage]:.1f}",
             f"{whole_now[stage]:.1f}"] for stage in now.index]  # fmt: skip
    sums = [paid[benchmark].loc[now.index].sum(), now.sum(), whole_paid.sum(), whole_now.sum()]
    rows.append(["**sum (thread-minutes)**", *(f"**{value:.1f}**" for value in sums)])
    rows.append([f"{jobs}-job wall, ideal (min)", *(f"{value / jobs:.1f}" for value in sums)])
    header = ["stage", f"{benchmark}, as paid", f"{benchmark}, retrained", "all, as paid", "all, estimated"]
    return _markdown(header, rows)


def stage_seconds(stage_times_csv: Path | str, **stages: str) -> str:
    """A sentence's "name 85 s, other 30 s": the build times of the named stages (their labels in a
    `tools/stage_times.py --csv` file; several labels joined by "+", and a label's builds on several
    benchmarks, are summed)."""
    seconds = pd.read_csv(stage_times_csv, keep_default_na=False).groupby("stage")["seconds"].sum()
    totals = {name: sum(seconds[s] for s in label.split("+")) for name, label in stages.items()}
    return ", ".join(f"{name} {value:.{0 if value >= 10 else 1}f} s" for name, value in totals.items())
