"""How much wider a report's intervals are than another's, per benchmark: the table in docs/results/cpu_all.md.

    fftool reproduce pipelines/cpu.toml --benchmarks all --set report.bootstrap_block=1 --out block1/
    python tools/interval_widening.py docs/results/cpu_all/all block1      # Markdown table on stdout

Both reports must come from the same evaluations (same seed); only the bootstrap differs. For each metric
and benchmark the table gives the range of (high - low) in the first report over (high - low) in the
second, over fftool's own predictors (the rows with intervals; the published methods have none), with the
median in brackets. A ratio above 1 means the first report's interval is wider.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

BENCHMARKS = ("eth", "hotel", "univ", "zara1", "zara2")
# metric: (the report's CSV, its column prefix after the benchmark, the pooled column)
METRICS = {
    "minADE": ("table2_ade_fde.csv", " minADE", "average"),
    "minFDE": ("table2_ade_fde.csv", " minFDE", "average"),
    "NC": ("table4_collisions.csv", "", "sum"),
}


def widths(report: Path, table: str, column: str) -> pd.Series:
    """high - low per predictor, indexed by the method's name; published rows (no interval) left out."""
    frame = pd.read_csv(report / table)
    frame = frame.set_index(frame.columns[0])
    return (frame[f"{column} high"] - frame[f"{column} low"]).dropna()


def cell(ratios: pd.Series) -> str:
    return f"{ratios.min():.1f}–{ratios.max():.1f} ({ratios.median():.1f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("wide", type=Path, help="report folder whose intervals are compared (e.g. block bootstrap)")
    parser.add_argument("narrow", type=Path, help="report folder they are compared with (e.g. window bootstrap)")
    args = parser.parse_args()
    rows = ["| metric | " + " | ".join(BENCHMARKS) + " | average / sum |", "|---|" + "---:|" * (len(BENCHMARKS) + 1)]
    for metric, (table, suffix, pooled) in METRICS.items():
        cells = []
        for place in (*BENCHMARKS, pooled):
            column = f"{place}{suffix}"
            try:
                ratios = widths(args.wide, table, column) / widths(args.narrow, table, column)
            except (OSError, KeyError) as error:
                parser.error(
                    f"{table} in {args.wide} and {args.narrow}: needs the columns '{column} low/high' ({error})"
                )
            cells.append(cell(ratios.dropna()))
        rows.append(f"| {metric} | " + " | ".join(cells) + " |")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
