"""Benchmark: learning curves of CVAE training recipes, time-to-accuracy, one run, same process.

Run: `python3 -m nox -s convergence` (or `python benchmarks/bench_convergence.py [--benchmark zara1]
[--variant baseline] [--recipe NAME=PROFILE ...] [--set NAME:section.key=value ...] [--val-windows 300]`).
Each recipe is a pipeline profile (its `[cvae]` section) plus overrides; recipes train one after the
other on the same benchmark, variant and validation windows. After every epoch the validation
minADE/minFDE@20 (ground-truth goals) is recorded against training seconds (validation excluded) and
agent-windows seen. Writes `<out>.csv` (every epoch of every recipe) and `<out>.png` (one line per
recipe), and prints the minutes each recipe needs to reach validation minADE@20 <= 0.30 m and 0.25 m.
Choices between recipes are made on these validation curves only, never on test numbers.
"""

from __future__ import annotations

import argparse
import csv
import tempfile
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_RAW = ROOT / ".." / "shared" / "data" / "eth_ucy" / "raw"
DEFAULT_RECIPES = (  # add `--recipe cpu=pipelines/cpu.toml` for the cpu profile's curve (~30 min more)
    f"old-quick={ROOT / 'benchmarks' / 'recipes' / 'old_quick.toml'}",
    f"quick={ROOT / 'pipelines' / 'quick.toml'}",
)
THRESHOLDS_M = (0.30, 0.25)


def _train(name: str, profile: Path, overrides: list[str], args: argparse.Namespace, store) -> list[dict]:
    """Train one recipe to the end of its budget; its log rows, tagged with the recipe's name."""
    from fftool import pipeline
    from fftool.config import load_config
    from fftool.stages import cvae
    from fftool.stages.contract import StageContext

    fixed = {
        "data.raw_dir": str(args.raw.resolve()),
        "cvae.variant": args.variant,
        "cvae.val_max_windows": args.val_windows,
    }
    cfg = load_config(profile, overrides, fixed)
    built = pipeline.run(cfg, store, ["forces"])
    print(f"== {name}: {profile.name} {' '.join(overrides)}", flush=True)
    with tempfile.TemporaryDirectory() as work:
        out, scratch = Path(work) / "out", Path(work) / "scratch"
        out.mkdir()
        started = time.perf_counter()
        on_epoch = lambda row: print(  # noqa: E731
            f"  epoch {row['epoch']:>3}  train {row['train_seconds']:7.1f} s  "
            f"val minADE {row['val_min_ade@20_m']:.3f}  minFDE {row['val_min_fde@20_m']:.3f}",
            flush=True,
        )
        ctx = StageContext(out, scratch, benchmark=args.benchmark, device_name="cpu", on_epoch=on_epoch)
        stats = cvae.train(cfg.cvae, cfg.forces, built["windows"], built["forces"], ctx)
        print(f"  {time.perf_counter() - started:.0f} s in all", flush=True)
    return [{"recipe": name, **row} for row in stats["log"]]


def _constant_velocity(args: argparse.Namespace, store, profile: Path) -> tuple[float, float]:
    """Validation minADE/minFDE@20 of the constant-velocity reference on the recipes' validation windows."""
    from fftool import pipeline
    from fftool.config import EvaluateConfig, load_config
    from fftool.learning import cvae_model
    from fftool.learning.batches import load_scene_set
    from fftool.learning.protocols import constant_velocity
    from fftool.learning.training import generator

    cfg = load_config(profile, [], {"data.raw_dir": str(args.raw.resolve()), "cvae.val_max_windows": args.val_windows})
    built = pipeline.run(cfg, store, ["forces"])
    val = load_scene_set(built["windows"], built["forces"], args.benchmark, "val")
    noise, gen = EvaluateConfig(), generator(0, torch.device("cpu"))
    return cvae_model.val_metrics(
        val,
        cvae_model.val_windows(val, cfg.cvae),
        cfg.cvae,
        int(built["windows"].manifest.stats["obs_len"]),
        torch.device("cpu"),
        lambda p: constant_velocity(
            p.past_pos, p.future_pos.shape[2], 20, noise.cv_angle_std_deg, noise.cv_speed_std, gen
        ),
    )


def _minutes_to(rows: list[dict], threshold: float) -> float | None:
    """Training minutes until validation minADE@20 first reaches `threshold` (None: never)."""
    hits = [row["train_seconds"] for row in rows if row["val_min_ade@20_m"] <= threshold]
    return min(hits) / 60 if hits else None


def _plot(rows: list[dict], names: list[str], cv: tuple[float, float], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5), sharey="row")
    for name in names:
        mine = [row for row in rows if row["recipe"] == name]
        minutes = [row["train_seconds"] / 60 for row in mine]
        seen = [row["agent_windows_seen"] / 1000 for row in mine]
        for line, metric in enumerate(("val_min_ade@20_m", "val_min_fde@20_m")):
            values = [row[metric] for row in mine]
            axes[line, 0].plot(minutes, values, marker=".", label=name)
            axes[line, 1].plot(seen, values, marker=".", label=name)
    for column, xlabel in enumerate(("training CPU minutes", "agent-windows seen (thousands)")):
        axes[1, column].set_xlabel(xlabel)
        for threshold in THRESHOLDS_M:
            axes[0, column].axhline(threshold, color="grey", lw=0.6, ls=":")
        for line in (0, 1):
            axes[line, column].axhline(cv[line], color="black", lw=1, ls="--", label="constant velocity@20")
    axes[0, 0].set_ylabel("val minADE@20 (m)")
    axes[1, 0].set_ylabel("val minFDE@20 (m)")
    axes[0, 0].legend()
    for ax in axes.flat:
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--raw", type=Path, default=DEFAULT_RAW)
    parser.add_argument("--root", type=Path, default=ROOT / "artifacts", help="artifact root for ingest/forces")
    parser.add_argument("--benchmark", default="zara1")
    parser.add_argument("--variant", default="baseline")
    parser.add_argument(
        "--recipe",
        action="append",
        metavar="NAME=PROFILE",
        help="repeatable; default: " + ", ".join(spec.split("=")[0] for spec in DEFAULT_RECIPES),
    )
    parser.add_argument("--set", action="append", default=[], metavar="NAME:section.key=value")
    parser.add_argument("--val-windows", type=int, default=300, help="validation windows, the same for all")
    parser.add_argument("--threads", type=int, default=torch.get_num_threads())
    parser.add_argument("--out", type=Path, default=None, help="CSV/PNG path stem")
    args = parser.parse_args()

    from rich.console import Console
    from rich.table import Table

    from fftool.artifacts.store import ArtifactStore

    torch.set_num_threads(args.threads)
    recipes = [spec.split("=", 1) for spec in (args.recipe or DEFAULT_RECIPES)]
    names = [name for name, _ in recipes]
    overrides = {name: [] for name in names}
    for item in args.set:
        name, _, override = item.partition(":")
        if name not in overrides:
            parser.error(f"--set {item!r}: no recipe named {name!r} (recipes: {', '.join(names)})")
        overrides[name].append(override)
    out = args.out or ROOT / "benchmarks" / "results" / f"convergence_{args.benchmark}_{args.variant}"
    out.parent.mkdir(parents=True, exist_ok=True)

    store = ArtifactStore(args.root)
    cv = _constant_velocity(args, store, Path(recipes[0][1]))
    print(f"constant velocity@20 on the same validation windows: minADE {cv[0]:.3f}  minFDE {cv[1]:.3f}")
    rows: list[dict] = []
    for name, profile in recipes:
        rows += _train(name, Path(profile), overrides[name], args, store)
        with open(out.with_suffix(".csv"), "w", newline="") as handle:  # after every recipe: nothing lost
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    title = f"{args.variant} on {args.benchmark}: validation minADE/minFDE@20 ({args.val_windows} windows)"
    _plot(rows, names, cv, out.with_suffix(".png"), title)

    table = Table(title=f"time-to-accuracy, {title}, {args.threads} threads")
    table.add_column("recipe")
    for column in ("epochs", "train min", "best val minADE", "best val minFDE"):
        table.add_column(column, justify="right")
    for threshold in THRESHOLDS_M:
        table.add_column(f"min to ≤ {threshold:.2f} m", justify="right")
        table.add_column("× first", justify="right")
    reference = [row for row in rows if row["recipe"] == names[0]]
    for name in names:
        mine = [row for row in rows if row["recipe"] == name]
        cells = [
            name,
            str(len(mine)),
            f"{mine[-1]['train_seconds'] / 60:.1f}",
            f"{min(row['val_min_ade@20_m'] for row in mine):.3f}",
            f"{min(row['val_min_fde@20_m'] for row in mine):.3f}",
        ]
        for threshold in THRESHOLDS_M:
            minutes, base = _minutes_to(mine, threshold), _minutes_to(reference, threshold)
            cells.append("never" if minutes is None else f"{minutes:.1f}")
            cells.append(f"{base / minutes:.1f}" if minutes and base else "")
        table.add_row(*cells)
    table.add_row("constant velocity@20", "", "", f"{cv[0]:.3f}", f"{cv[1]:.3f}")
    Console(width=150).print(table)
    print(f"wrote {out.with_suffix('.csv')} and {out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
