"""What a smaller training budget would cost, read from the shipped models' validation curves.

    python tools/budget_curves.py --models models/cpu --fraction 0.5    # Markdown table on stdout

Every shipped model keeps its per-epoch validation log (`log.csv`). For each one the table gives the
validation metric its best epoch was chosen by (`best_val_...` in its manifest): its best over the whole
budget, and its best over the first `fraction` of the epochs, the score a run stopped
there would keep. It is an upper bound on the cost of the smaller budget, not its value: a run planned for
fewer epochs decays its learning rate to zero by its own last epoch (cosine schedule) and usually ends
lower than the longer run did at the same epoch.
Validation parts only: the test parts are never read.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

from fftool.artifacts.store import Manifest


def curve(folder: Path, metric: str) -> list[float]:
    with (folder / "log.csv").open() as log:
        return [float(row[metric]) for row in csv.DictReader(log)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=Path, default=Path("models/cpu"))
    parser.add_argument("--fraction", type=float, default=0.5, help="share of the epochs kept (0-1]")
    args = parser.parse_args()
    first = f"best of the first {args.fraction:.0%}"
    print(f"| model | metric (val) | best of all epochs | {first} | cost | thread-minutes saved |")
    print("|---|---|---:|---:|---:|---:|")
    saved_total = spent_total = 0.0
    for manifest_path in sorted(args.models.glob("*/*/manifest.json")):
        manifest = Manifest.from_json(manifest_path.read_text())
        kind, stats = manifest.kind, manifest.stats
        metric = next(key.removeprefix("best_") for key in stats if key.startswith("best_val_"))
        values = curve(manifest_path.parent, metric)
        kept = max(1, math.ceil(len(values) * args.fraction))
        full, short = min(values), min(values[:kept])
        seconds = manifest.thread_seconds()
        saved = seconds * (1 - kept / len(values))
        saved_total, spent_total = saved_total + saved, spent_total + seconds
        name = f"{stats['benchmark']}/{stats.get('variant') or 'goal-unet'}{'/dlow' if kind == 'dlow' else ''}"
        print(
            f"| {name} | {metric} | {full:.3f} | {short:.3f} | {short - full:+.3f} ({short / full - 1:+.0%}) "
            f"| {saved / 60:.1f} |"
        )
    print(f"\n{spent_total / 60:.0f} thread-minutes trained; the smaller budget saves about {saved_total / 60:.0f}.")


if __name__ == "__main__":
    main()
