"""The stage contract: what every stage module declares, and what the engine hands its `build`.

A stage module (`fftool/stages/<kind>.py`, named after the artifact kind it makes) exposes `NAME`,
`VERSION`, `INPUTS`, `build(cfg, inputs, ctx) -> stats` and `STAGE`, the `Stage` that tells the engine
(`fftool.pipeline`) everything else: its configuration section, the command that makes it, raw inputs
hashed into its fingerprint, and whether it is built once per benchmark. Stages never import each
other; they agree on artifacts (`fftool.artifacts.schema`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from fftool.artifacts.store import Artifact
from fftool.config import PipelineConfig
from fftool.errors import FftoolError

OnProgress = Callable[[str, int, "int | None"], None]  # (phase, done, total)
OnEpoch = Callable[[dict[str, Any]], None]  # one training epoch's log row


def _ignore(*_: Any) -> None:
    return None


@dataclass(frozen=True)
class StageContext:
    """Where a build writes (`out_dir`), what it keeps across attempts (`scratch`), how it runs and reports."""

    out_dir: Path
    scratch: Path  # kept when a build fails (resume state); removed once the artifact is installed
    benchmark: str | None = None  # set for per-benchmark stages
    device_name: str = "auto"  # auto | cpu | cuda
    on_progress: OnProgress = _ignore
    on_epoch: OnEpoch = _ignore

    def device(self) -> Any:
        """The torch device to run on (imported here, so stages without torch never load it)."""
        import torch

        if self.device_name == "auto":
            return torch.device("cuda" if torch.cuda.is_available() else "cpu")
        if self.device_name == "cuda" and not torch.cuda.is_available():
            raise FftoolError("--device cuda was asked for, but torch sees no CUDA device; use --device auto or cpu")
        return torch.device(self.device_name)

    def need_benchmark(self) -> str:
        if self.benchmark is None:
            raise FftoolError("this stage is built once per benchmark, and none was given")
        return self.benchmark


Build = Callable[[PipelineConfig, Mapping[str, Artifact], StageContext], dict[str, Any]]


@dataclass(frozen=True)
class Stage:
    """One node of the DAG: its name, what it reads, how it is configured and built."""

    name: str
    version: int
    inputs: tuple[str, ...]
    command: str  # the CLI command that makes it, for error messages
    section: Callable[[PipelineConfig], BaseModel]  # the configuration its fingerprint hashes
    build: Build
    description: Callable[[PipelineConfig, str | None], str]  # the progress bar's label
    external_inputs: Callable[[PipelineConfig], dict[str, str]] = field(default=lambda cfg: {})
    per_benchmark: bool = False  # one artifact per leave-one-out benchmark (the benchmark is a parameter)
    # Upstream stages that depend on the configuration (a subset of `inputs`); default: all of them.
    needs: Callable[[PipelineConfig], tuple[str, ...]] | None = None
    # The command's options that select this artifact (e.g. ` --variant dr`), for error messages.
    command_args: Callable[[PipelineConfig], str] = field(default=lambda cfg: "")
    # The parts it reads of upstream artifacts whose stage has a `view` (e.g. {"forces": ("f_dr",)}):
    # its fingerprint then hashes only the upstream parameters those parts depend on.
    reads: Callable[[PipelineConfig], Mapping[str, tuple[str, ...]]] = field(default=lambda cfg: {})
    # For a producer: its parameters (from its resolved params) that the named parts of its artifact depend on.
    view: Callable[[Mapping[str, Any], tuple[str, ...]], dict[str, Any]] | None = None
    # Trains data-parallel under torchrun: every rank runs `build`, rank 0 alone installs (pipeline._follow).
    distributed: bool = False

    def inputs_for(self, cfg: PipelineConfig | None) -> tuple[str, ...]:
        return self.inputs if self.needs is None or cfg is None else self.needs(cfg)

    def command_line(self, cfg: PipelineConfig, benchmark: str | None) -> str:
        """The command that makes this stage's artifact for `cfg` (and `benchmark`), as a user would type it."""
        where = f" --benchmarks {benchmark}" if self.per_benchmark and benchmark else ""
        return f"{self.command}{where}{self.command_args(cfg)}"
