"""One training step of the goal U-Net (inputs, forward, loss, backward, optimizer) with its weights in the
default layout and channels-last, in the same process on the same batches: the time of each, their ratio, and
the largest difference of their outputs (the two layouts compute the same function).

    python benchmarks/bench_goal_step.py --profile pipelines/cpu.toml --benchmark zara1 --steps 30

Reads the windows and maps artifacts of the profile from the artifact store (built if missing); one thread.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time
from pathlib import Path

import torch

from fftool import pipeline
from fftool.artifacts.store import ArtifactStore
from fftool.config import load_config
from fftool.learning.goal_model import goal_inputs, goal_loss
from fftool.learning.training import make_optimizer
from fftool.science.heatmaps import world_to_cells
from fftool.stages.goal import _trainer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--profile", type=Path, default=Path("pipelines/cpu.toml"))
    parser.add_argument("--benchmark", default="zara1")
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--root", type=Path, default=Path("artifacts"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    cfg = load_config(args.profile)
    store = ArtifactStore(args.root)
    built = pipeline.run(cfg, store, ["windows", "maps"], runtime=pipeline.Runtime(), benchmark=args.benchmark)
    goal = cfg.goal
    # the training stage's own data and model (channels-last), and a copy of the model in the default layout
    trainer = _trainer(goal, cfg.goals, args.benchmark, built["windows"], built["maps"], torch.device("cpu"))
    obs_len, pred_len, scenes, scene_maps = trainer.obs_len, trainer.pred_len, trainer.train_scene, trainer.maps
    xy_all = trainer.train_xy
    models = {"channels_last": trainer.model}
    models["default"] = copy.deepcopy(trainer.model).to(memory_format=torch.contiguous_format)
    optimizers = {name: make_optimizer(m, goal.optimizer, goal.lr, goal.weight_decay) for name, m in models.items()}
    seconds: dict[str, list[float]] = {name: [] for name in models}
    gen = torch.Generator().manual_seed(0)
    largest = 0.0
    for step in range(args.steps + 3):  # the first three warm up
        index = torch.randint(len(xy_all), (goal.batch_size,), generator=gen)
        xy, zeros = xy_all[index], torch.zeros(goal.batch_size)
        mirror = torch.rand(goal.batch_size, generator=gen) < 0.5
        neighbours = trainer.train_neighbours  # the profile's goal U-Net may read the other walkers
        others = None if neighbours is None else neighbours.observed(index, obs_len)
        outputs = {}
        for name in ["default", "channels_last"] if step % 2 else ["channels_last", "default"]:  # alternate
            started = time.perf_counter()
            x, center, R = goal_inputs(
                xy[:, :obs_len], scenes[index], scene_maps, goal, zeros, mirror, pred_len, others
            )  # fmt: skip
            logits = models[name](x)
            future = world_to_cells(xy[:, obs_len + pred_len - 1 :], center, R, goal.resolution_m, goal.crop_cells)
            loss = goal_loss(logits, future, goal)[0]
            optimizers[name].zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(models[name].parameters(), goal.grad_clip)
            optimizers[name].step()
            if step >= 3:
                seconds[name].append(time.perf_counter() - started)
            outputs[name] = logits.detach()
        if step == 0:  # the same weights yet: the same function
            largest = float((outputs["default"] - outputs["channels_last"]).abs().max())
    median = {name: statistics.median(values) * 1000 for name, values in seconds.items()}
    print(f"goal U-Net training step, {args.benchmark}, batch {goal.batch_size}, widths {list(goal.widths)}, "
          f"{goal.crop_cells}² crop, one thread, median of {args.steps}:")  # fmt: skip
    for name, ms in median.items():
        print(f"  {name:>13}: {ms:7.1f} ms")
    print(f"  ratio default / channels_last: {median['default'] / median['channels_last']:.2f}×")
    print(f"  largest logit difference at the first step: {largest:.2e}")


if __name__ == "__main__":
    main()
