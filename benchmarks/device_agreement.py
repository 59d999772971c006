"""The shipped models on a GPU against the same models on the CPU: how far apart their futures are, and how
long a whole recording takes on each, in one process.

For each shipped zara1 model of a profile, `predict_tracks` runs on zara1's test recording (crowds_zara01,
every agent with 8 observed steps, about 3,000 agent-windows) on the CPU and on CUDA. Compared: the
most-likely future (the prior's mean code; deterministic), goal variants steering toward a goal passed per
agent (the agent's last position in the file: a numerical check, not an accuracy one), as the largest and
the mean distance between the two devices' positions. Timed, after that call: K = 20 futures at every 10th
time of the recording (goal variants with their goal U-Net's goals) on each device; the draws differ between
devices (CUDA and CPU generators are not the same streams), so they are timed, not compared.

    python benchmarks/device_agreement.py --out device_agreement.csv   # needs a CUDA device
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from fftool.api import load, load_goal_sampler, predict_tracks
from fftool.dataset.rawfiles import read_raw
from fftool.variants import reads_goal
from fftool.zoo import profile_config

DEFAULT_RAW = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "eth_ucy" / "raw"
VARIANTS = ("baseline", "goal", "dr", "re")
TIMED_EVERY = 10  # every 10th time of the recording


def _tracks(path: Path) -> pd.DataFrame:
    """A raw recording as `predict_tracks` takes a user's tracks: rows (time_s, agent, x, y), by agent then time,
    with the frame stride and step the cpu profile ingests it with."""
    ingest = profile_config("cpu").ingest
    raw = read_raw(path, frame_stride=ingest.frame_stride)
    seconds_per_frame = ingest.dt_s / ingest.frame_stride
    tracks = pd.DataFrame({"time_s": raw.frame_id * seconds_per_frame, "agent": raw.ped_id, "x": raw.x, "y": raw.y})
    return tracks.sort_values(["agent", "time_s"], kind="stable").reset_index(drop=True)


def _synchronize(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--raw", type=Path, default=DEFAULT_RAW)
    parser.add_argument("--profile", default="cpu")
    parser.add_argument("--device", default="cuda", help="the device compared with the CPU")
    parser.add_argument("--out", type=Path, required=True, help="CSV, one row per model")
    args = parser.parse_args()
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        parser.error(f"--device {args.device}: torch sees no CUDA device here")

    path = args.raw / "all_data" / "crowds_zara01.txt"
    tracks = _tracks(path)
    last = tracks.groupby("agent")[["x", "y"]].last()
    goals = {agent: (float(x), float(y)) for agent, (x, y) in last.iterrows()}
    rows = []
    for variant in VARIANTS:
        name = f"{args.profile}/zara1/{variant}"
        found: dict[str, dict[str, object]] = {}
        for device in ("cpu", args.device):
            model = load(name, device=device)
            passed = goals if reads_goal(variant) else None
            sampler = load_goal_sampler(name, device=device) if reads_goal(variant) else None
            k = 1 if model.sampler is None else model.sampler.k  # a DLow sampler decodes its own K beside it
            likely, _ = predict_tracks(model, tracks, source=path, at="all", k=k, goals=passed, most_likely=True)
            times = sorted(likely.time_s.unique())[::TIMED_EVERY]  # the K = 20 call's prediction times
            started = time.perf_counter()
            futures, _ = predict_tracks(model, tracks, source=path, at=times, goal_sampler=sampler)
            _synchronize(device)
            seconds = time.perf_counter() - started
            windows = futures.groupby(["time_s", "agent"]).ngroups
            found[device] = {"likely": likely, "seconds": seconds, "windows": windows}
        a, b = found["cpu"]["likely"], found[args.device]["likely"]
        gap = np.hypot(a.x.to_numpy() - b.x.to_numpy(), a.y.to_numpy() - b.y.to_numpy())
        row = {
            "model": name,
            "agent_windows": a.groupby(["time_s", "agent"]).ngroups,
            "most_likely_max_m": float(gap.max()),
            "most_likely_mean_m": float(gap.mean()),
            "k20_agent_windows": found["cpu"]["windows"],
            "k20_cpu_s": round(float(found["cpu"]["seconds"]), 3),
            f"k20_{args.device}_s": round(float(found[args.device]["seconds"]), 3),
            "cpu_threads": torch.get_num_threads(),
            "gpu": torch.cuda.get_device_name() if torch.cuda.is_available() else "",
        }
        print(row, flush=True)
        rows.append(row)
    with args.out.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


if __name__ == "__main__":
    main()
