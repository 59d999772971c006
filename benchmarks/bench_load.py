"""What verifying a model on every load costs: the checks beside the load and a small prediction.

`fftool.api.load` (and so `fftool predict`) checks each file of a model against its manifest (sha256) and
the manifest against its fingerprint before use. This times, for a shipped model (default cpu/eth/dr, with
its DLow sampler where it has one), medians over `--repeats`: the verification alone (`ArtifactStore.check_inputs`
on the CVAE and its windows chain), `api.load` as a whole, and one small prediction (2 agents, K = 20).
Run: `OMP_NUM_THREADS=1 python benchmarks/bench_load.py --threads 1`.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch


def median_ms(call: object, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        call()
        times.append(time.perf_counter() - started)
    return statistics.median(times) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="cpu/eth/dr")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    from fftool import zoo
    from fftool.api import load

    bundle = zoo.find(args.model)
    checked = {"cvae": bundle.cvae} | ({"dlow": bundle.dlow} if bundle.dlow else {})
    size = sum(f.stat().st_size for a in checked.values() for f in a.path.iterdir() if f.is_file())
    model = load(args.model)
    steps = np.arange(8)[:, None]
    past = np.stack([[0.0, 0.0] + steps * [0.5, 0.0], [6.0, 1.0] + steps * [-0.45, 0.0]])[None]
    mask, goals = np.ones((1, 2), bool), past[:, :, -1] + [[6.0, 0.0], [-6.0, 0.0]]
    rows = {
        "verify the files (sha256 vs manifest)": median_ms(lambda: bundle.store.check_inputs(checked), args.repeats),
        "api.load, verification included": median_ms(lambda: load(args.model), args.repeats),
        "one prediction (2 agents, K = 20)": median_ms(lambda: model.predict(past, mask, goals=goals), args.repeats),
    }
    print(f"{args.model}: {size / 2**20:.2f} MiB of model files, {torch.get_num_threads()} thread(s), "
          f"medians of {args.repeats}")  # fmt: skip
    print("| step | median (ms) |\n|---|---:|")
    for name, ms in rows.items():
        print(f"| {name} | {ms:.1f} |")


if __name__ == "__main__":
    main()
