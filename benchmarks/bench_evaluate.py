"""Evaluation speed: a whole test part, K = 20, d_model 256, forces recomputed while decoding.

Times `fftool.stages.evaluate.sample_and_score` (the `evaluate` stage's work: batching, sampling, metrics,
Parquet) on the univ test part (24,334 valid agent-windows) with an untrained `re` model of AgentFormer's size (the cost
does not depend on the weights) under the oracle goal protocol, and compares it with the official
AgentFormer code's projected 80 minutes on this machine (research/agentformer.md §10.4).
Run: `python benchmarks/bench_evaluate.py [--benchmark univ] [--variant re]`.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import torch

DEFAULT_RAW = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "eth_ucy" / "raw"
OFFICIAL_MINUTES = {"univ": 80.0, "zara1": 4.0, "zara2": 9.9, "eth": 0.8, "hotel": 2.1}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--raw", type=Path, default=DEFAULT_RAW)
    parser.add_argument("--benchmark", default="univ")
    parser.add_argument("--variant", default="re")
    parser.add_argument("--protocol", default="oracle")
    args = parser.parse_args()

    from rich.console import Console
    from rich.table import Table

    from fftool import pipeline
    from fftool.artifacts.schema import CVAE_MODEL_FILE
    from fftool.artifacts.store import ArtifactStore
    from fftool.config import CVAEConfig, EvaluateConfig, ForcesConfig, load_config
    from fftool.learning import cvae_model
    from fftool.learning.training import save_checkpoint
    from fftool.stages import evaluate
    from fftool.ui import err_console

    with tempfile.TemporaryDirectory() as root:
        err_console.quiet = True
        built = pipeline.run(
            load_config(None, [f"data.raw_dir={str(args.raw.resolve())!r}"]), ArtifactStore(root), ["forces"]
        )
        err_console.quiet = False
        cfg = CVAEConfig(variant=args.variant)
        torch.manual_seed(0)
        model_dir = Path(root) / "model"
        model_dir.mkdir()
        save_checkpoint(
            model_dir / CVAE_MODEL_FILE,
            {
                "state_dict": cvae_model.build_model(cfg).state_dict(),
                "config": cfg.model_dump(mode="json"),
                "forces_config": ForcesConfig().model_dump(mode="json"),
                "dt_s": 0.4,
            },
        )
        artifact = type("Artifact", (), {"file": lambda self, name: model_dir / name})()
        out = Path(root) / "out"
        out.mkdir()
        started = time.perf_counter()
        stats = evaluate.sample_and_score(
            EvaluateConfig(protocol=args.protocol),
            args.benchmark,
            built["windows"],
            built["forces"],
            artifact,
            None,
            out,
            torch.device("cpu"),
        )
        seconds = time.perf_counter() - started

    official = OFFICIAL_MINUTES.get(args.benchmark)
    table = Table(title=f"evaluation of {args.benchmark} test, {args.variant}, d_model 256, K = 20, this CPU")
    for column in ("agent-windows", "minutes", "agent-windows / s", "official minutes", "speed-up"):
        table.add_column(column, justify="right")
    table.add_row(
        f"{stats['agent_windows']:,}",
        f"{seconds / 60:.2f}",
        f"{stats['agent_windows'] / seconds:.1f}",
        f"{official:.1f}" if official else "",
        f"{official * 60 / seconds:.1f}×" if official else "",
    )
    table.caption = f"{torch.get_num_threads()} torch threads; sampling alone {stats['seconds']:.1f} s"
    Console().print(table)


if __name__ == "__main__":
    main()
