"""Benchmark: does DLow help? Validation curves of a profile's CVAEs and their DLow samplers, and constant
velocity, on the same validation windows, against CPU minutes.

Run: `python benchmarks/bench_dlow.py --profile pipelines/quick.toml [--variants baseline,goal,dr,re]
[--benchmark zara1] [--set section.key=value ...] [--out benchmarks/results/dlow_quick_zara1]`.
Trains (or reuses, from the artifact root) each variant's CVAE and its DLow sampler under the profile, with
the DLow validation subset set to the CVAE's (same size and seed: the same windows). Constant velocity is
scored on those windows with fftool's noise setting (the evaluate section's) and with the best of a grid of
noise settings chosen on these validation windows. Writes `<out>.csv` (every epoch of every curve), `<out>.png`
and `<out>.md` (the best validation numbers of each, and whether DLow beats the CVAE's own samples). Every
choice made from it (which variants keep DLow, its budget) is made on validation, never on test numbers.
"""

from __future__ import annotations

import argparse
import csv
import itertools
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]


def _cv_scorer(cfg, store, benchmark: str):
    """Constant velocity's minADE/minFDE@K on the CVAE's validation subset, as a function of its noise (the
    validation windows are read once)."""
    from fftool import pipeline
    from fftool.learning.batches import load_scene_set
    from fftool.learning.cvae_model import val_metrics, val_windows
    from fftool.learning.protocols import constant_velocity
    from fftool.learning.training import generator

    windows = pipeline.run(cfg, store, ["windows"])["windows"]
    val = load_scene_set(windows, None, benchmark, "val", reads=())
    subset, obs_len, k = val_windows(val, cfg.cvae), int(windows.manifest.stats["obs_len"]), cfg.evaluate.k

    def score(angle: float, speed: float) -> tuple[float, float]:
        gen = generator(cfg.evaluate.seed, torch.device("cpu"))

        def predict(prepared):  # in the window's frame: constant velocity is frame-free
            return constant_velocity(prepared.past_pos, prepared.future_pos.shape[2], k, angle, speed, gen)

        return val_metrics(val, subset, cfg.cvae, obs_len, torch.device("cpu"), predict)

    return score


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", type=Path, default=ROOT / "pipelines" / "quick.toml")
    parser.add_argument("--benchmark", default="zara1")
    parser.add_argument("--variants", default="baseline,goal,dr,re")
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    parser.add_argument("--root", type=Path, default=Path("artifacts"))
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()

    from fftool import pipeline
    from fftool.artifacts.store import ArtifactStore
    from fftool.config import load_config

    out = args.out or ROOT / "benchmarks" / "results" / f"dlow_{args.profile.stem}_{args.benchmark}"
    store = ArtifactStore(args.root)
    base = load_config(args.profile, args.overrides)
    rows, best = [], {}
    for variant in args.variants.split(","):
        cfg = load_config(args.profile, [*args.overrides, f"cvae.variant='{variant}'"])
        cfg = cfg.model_copy(update={"dlow": cfg.dlow.model_copy(update={"val_max_windows": cfg.cvae.val_max_windows,
                                                                          "seed": cfg.cvae.seed})})  # fmt: skip
        built = pipeline.run(cfg, store, ["dlow"], benchmark=args.benchmark, runtime=pipeline.Runtime("cpu"))
        k = cfg.evaluate.k
        cvae_log, dlow_log = built["cvae"].manifest.stats["log"], built["dlow"].manifest.stats["log"]
        cvae_minutes = cvae_log[-1]["train_seconds"] / 60
        for name, log, offset in (("cvae", cvae_log, 0.0), ("dlow", dlow_log, cvae_minutes)):
            ade_key, fde_key = f"val_min_ade@{k}_m", f"val_min_fde@{k}_m"
            for row in log:
                minutes = offset + row["train_seconds"] / 60
                point = {"variant": variant, "curve": f"{variant} {name}", "epoch": row["epoch"]}
                rows.append(point | {"cpu_minutes": minutes, "val_min_ade": row[ade_key], "val_min_fde": row[fde_key]})
            kept = min(log, key=lambda r: r[ade_key])
            best[(variant, name)] = (kept[ade_key], kept[fde_key], offset + log[-1]["train_seconds"] / 60)
    ev = base.evaluate
    cv_score = _cv_scorer(base, store, args.benchmark)
    fftool_cv = cv_score(ev.cv_angle_std_deg, ev.cv_speed_std)
    grid = list(itertools.product((0.0, 5.0, 10.0, 15.0, 25.0), (0.0, 0.1, 0.2, 0.3)))
    tuned = {noise: cv_score(*noise) for noise in grid}
    tuned_noise = min(tuned, key=lambda noise: tuned[noise][0])

    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.with_suffix(".csv"), "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    _plot(rows, fftool_cv, tuned[tuned_noise], tuned_noise, out.with_suffix(".png"), args)
    lines = [f"# DLow on {args.benchmark}, profile {args.profile.name}: validation (the CVAE's subset)", "",
             f"Command: `python benchmarks/bench_dlow.py --profile {args.profile} --benchmark {args.benchmark} "
             f"--variants {args.variants}" + "".join(f" --set {o}" for o in args.overrides) + "`", "",
             "| curve | best val minADE / minFDE (m) | CPU minutes (training) |", "|---|---:|---:|"]  # fmt: skip
    for (variant, name), (ade, fde, minutes) in best.items():
        label = "CVAE samples" if name == "cvae" else "+ DLow"
        lines.append(f"| {variant} {label} | {ade:.3f} / {fde:.3f} | {minutes:.1f} |")
    noise = f"{ev.cv_angle_std_deg:g}°, {ev.cv_speed_std:g}"
    lines.append(f"| constant velocity, fftool's noise ({noise}) | {fftool_cv[0]:.3f} / {fftool_cv[1]:.3f} | |")
    chosen = tuned[tuned_noise]
    lines.append(
        f"| constant velocity, tuned on these windows ({tuned_noise[0]:g}°, {tuned_noise[1]:g}) | "
        f"{chosen[0]:.3f} / {chosen[1]:.3f} | |"
    )
    helps = {
        v: best[(v, "dlow")][0] < best[(v, "cvae")][0] and best[(v, "dlow")][1] < best[(v, "cvae")][1]
        for v in args.variants.split(",")
    }
    verdict = ", ".join(f"{v}: {'yes' if h else 'no'}" for v, h in helps.items())
    lines += ["", f"DLow helps (lower val minADE and minFDE than the CVAE's own samples): {verdict}"]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def _plot(rows, fftool_cv, tuned_cv, tuned_noise, path: Path, args) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharex=True)
    curves = sorted({r["curve"] for r in rows})
    colours = dict(zip(sorted({r["variant"] for r in rows}), plt.cm.tab10.colors))
    for ax, metric, cv_index in zip(axes, ("val_min_ade", "val_min_fde"), (0, 1)):
        for curve in curves:
            mine = [r for r in rows if r["curve"] == curve]
            ax.plot([r["cpu_minutes"] for r in mine], [r[metric] for r in mine], marker="o", markersize=3,
                    color=colours[mine[0]["variant"]], linestyle="-" if curve.endswith("dlow") else "--",
                    label=curve.replace(" cvae", " (CVAE samples)").replace(" dlow", " + DLow"))  # fmt: skip
        ax.axhline(fftool_cv[cv_index], color="grey", linestyle=":", label="constant velocity (fftool's noise)")
        ax.axhline(tuned_cv[cv_index], color="black", linestyle=":",
                   label=f"constant velocity (tuned: {tuned_noise[0]:g}°, {tuned_noise[1]:g})")  # fmt: skip
        ax.set_xlabel("CPU minutes of training (CVAE, then DLow)")
        ax.set_ylabel(
            f"{metric.replace('val_min_', 'validation min').upper().replace('VALIDATION', 'validation ')}@20 (m)"
        )
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{args.benchmark}, {args.profile.name}: CVAE samples vs DLow vs constant velocity (same windows)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
