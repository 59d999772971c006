"""The stage contract: what a stage module declares, and what the engine hands its `build`.

A stage module (`fftool/stages/<kind>.py`, named after the artifact kind it makes) exposes `STAGE`, a
`Stage`, whose `declare(cfg)` says in one place everything one build reads (`Reads`): the upstream
artifacts and which parts of each, the configuration keys (across sections, like DVC's `params:`),
the raw files by content hash, and the command line that makes it. The engine (`fftool.pipeline`)
computes the fingerprint from exactly that declaration and hands `build` a view of the configuration
that holds only the declared keys (`ConfigView`): reading any other key raises `UndeclaredRead`, so a
value that steers a build but not its fingerprint cannot exist. Stages never import each other; they
agree on artifacts (`fftool.artifacts.schema`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from pydantic import BaseModel

from fftool.artifacts.store import Artifact, BuildContext
from fftool.config import PipelineConfig, variant_section
from fftool.errors import FftoolError

OnProgress = Callable[[str, int, "int | None"], None]  # (phase, done, total)
OnEpoch = Callable[[dict[str, Any]], None]  # one training epoch's log row


def _ignore(*_: Any) -> None:
    return None


@dataclass(kw_only=True)
class StageContext(BuildContext):
    """The store's build context (where a build writes, `dir`; what it keeps across attempts, `scratch`; its
    `stats`) with what a stage needs besides: its benchmark, its device, whom it tells of its progress."""

    benchmark: str | None = None  # set for per-benchmark stages
    device_name: str = "auto"  # auto | cpu | cuda
    on_progress: OnProgress = _ignore
    on_epoch: OnEpoch = _ignore

    def device(self) -> Any:
        """The torch device to run on (`learning.devices.resolve`, imported here so torch-free stages stay so)."""
        from fftool.learning.devices import resolve

        return resolve(self.device_name)

    def need_benchmark(self) -> str:
        if self.benchmark is None:
            raise FftoolError("this stage is built once per benchmark, and none was given")
        return self.benchmark


@dataclass(frozen=True)
class Reads:
    """Everything one build reads, declared once; its fingerprint is computed from exactly this.

    params: configuration keys as "section.key", or "section.*" for a whole section. Keys of the stage's
        own section are recorded under their bare name; the section's keys a build does not read are
        recorded at their defaults (so a section's record has one layout, and the fingerprints made
        before this contract stay valid). Keys of other sections are recorded as "section.key".
    artifacts: upstream stage -> the parts of its artifact the build reads (None: all of it). Reading
        parts hashes only the upstream parameters those parts depend on (`Stage.parts`), and lets the
        build read those configuration keys too (they are in the fingerprint through that view).
    raw_files: a function giving raw input name -> sha256 of its bytes (files enter by content, never by path);
        called only when the files are needed, so a shipped model's recorded hashes can stand in for them.
    locations: configuration keys that say where the raw files lie: readable by the build, not hashed.
    command: the options of the stage's command that select this artifact (e.g. " --variant dr").
    """

    params: tuple[str, ...]
    artifacts: Mapping[str, tuple[str, ...] | None] = field(default_factory=dict)
    raw_files: Callable[[], Mapping[str, str]] = dict
    locations: tuple[str, ...] = ()
    command: str = ""


Build = Callable[["PipelineConfig", Mapping[str, Artifact], StageContext], dict[str, Any]]


@dataclass(frozen=True)
class Stage:
    """One node of the DAG: its name and version, what one build reads (`declare`), and how it is built."""

    name: str
    version: int  # the artifact's schema version (fftool.artifacts.schema.VERSIONS)
    command: str  # the CLI command that makes it, for messages
    label: str  # what the progress bar calls a build
    declare: Callable[[PipelineConfig], Reads]
    build: Build  # gets a ConfigView of the declared keys, the declared artifacts and a StageContext
    section: str | None = None  # its own configuration section (see Reads.params)
    per_benchmark: bool = False  # one artifact per leave-one-out benchmark (the benchmark is a parameter)
    # Trains data-parallel under torchrun: every rank runs `build`, rank 0 alone installs (pipeline._follow).
    distributed: bool = False
    # For a producer whose consumers may read parts of its artifact: the keys of its section each part
    # depends on (forces.ARRAY_PARAMS), so a consumer of some parts is fingerprinted on those keys alone.
    parts: Mapping[str, frozenset[str]] = field(default_factory=dict)

    def view_keys(self, parts: tuple[str, ...]) -> frozenset[str]:
        """The keys of this stage's section that the named parts of its artifact depend on (`parts`)."""
        unknown = set(parts) - set(self.parts)
        if unknown:
            raise KeyError(f"stage {self.name!r} has no parts {sorted(unknown)}; its parts: {sorted(self.parts)}")
        return frozenset().union(*(self.parts[part] for part in parts))

    def describe(self, reads: Reads, benchmark: str | None) -> str:
        where = f" ({benchmark})" if self.per_benchmark and benchmark else ""
        return f"{self.label}{reads.command}{where}"

    def command_line(self, reads: Reads, benchmark: str | None) -> str:
        """The command that makes this build's artifact, as a user would type it."""
        where = f" --benchmarks {benchmark}" if self.per_benchmark and benchmark else ""
        return f"{self.command}{where}{reads.command}"


class UndeclaredRead(FftoolError):
    """A build read a configuration key its declaration does not list: a bug in the stage, found loudly."""


def allowed_keys(cfg: PipelineConfig, params: tuple[str, ...]) -> frozenset[str]:
    """ "section.key" of every key `params` names ("section.*" expands to the whole section)."""
    keys: set[str] = set()
    for param in params:
        section, _, key = param.partition(".")
        names = type(getattr(cfg, section)).model_fields
        if key == "*":
            keys |= {f"{section}.{name}" for name in names}
        elif key in names:
            keys.add(param)
        else:
            raise KeyError(f"declared parameter {param!r} is not a configuration key")
    return frozenset(keys)


class SectionView:
    """One configuration section as a build sees it: the declared keys, nothing else."""

    def __init__(self, section: BaseModel, name: str, allowed: frozenset[str], stage: str) -> None:
        self._section, self._name, self._allowed, self._stage = section, name, allowed, stage

    def __getattr__(self, key: str) -> Any:
        if key in type(self._section).model_fields and key not in self._allowed:
            raise UndeclaredRead(
                f"stage {self._stage!r} read {self._name}.{key}, which its declaration (STAGE.declare in "
                f"fftool/stages/{self._stage}.py) does not list; declare it so that it enters the fingerprint"
            )
        if key.startswith("model_") and key != "model_dump":
            raise UndeclaredRead(f"stage {self._stage!r} used {self._name}.{key} on a section it reads only in part")
        return getattr(self._section, key)

    def model_dump(self, **kwargs: Any) -> dict[str, Any]:
        """The declared keys only (e.g. the force constants a CVAE's decoder was trained with)."""
        return {k: v for k, v in self._section.model_dump(**kwargs).items() if k in self._allowed}


class ConfigView:
    """The configuration as a build sees it: whole sections where every key is declared, a `SectionView`
    where some are, and a view that refuses every key where none is."""

    def __init__(self, cfg: PipelineConfig, allowed: frozenset[str], stage: str) -> None:
        self._cfg, self._allowed, self._stage = cfg, allowed, stage

    def __getattr__(self, name: str) -> Any:
        section = variant_section(self._cfg, name)
        keys = frozenset(key for key in type(section).model_fields if f"{name}.{key}" in self._allowed)
        return (
            section if keys == frozenset(type(section).model_fields) else SectionView(section, name, keys, self._stage)
        )
