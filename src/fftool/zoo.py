"""The model zoo: trained models shipped in the repository, keyed by the fingerprints the code computes.

`models/<profile>/` is an artifact store of its own (the same layout, manifests and hashes as any store)
holding, per benchmark, what `pipelines/<profile>.toml` trains: the goal U-Net, the four CVAEs and the DLow
samplers the profile keeps. A shipped model is current when the fingerprint the code computes today for its
stage, benchmark and variant under that profile equals the one it was trained under; `install` copies
current models into a user's store (every file checked against its manifest first), so `reproduce` finds
them built and trains nothing. Names read `<profile>/<benchmark>/<variant>` (e.g. `cpu/zara1/dr`).
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import os
import re
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fftool.artifacts.hashing import sha256_file
from fftool.artifacts.store import MANIFEST, Artifact, ArtifactStore, check_schema
from fftool.config import EvaluateConfig, FairCode, PipelineConfig, load_config, predictor_config, variant_section
from fftool.errors import FftoolError, IntegrityError, UsageError
from fftool.outputs import replacing_file
from fftool.variants import VARIANTS, reads_goal

if TYPE_CHECKING:
    from fftool.pipeline import Resolved

ENV_MODELS = "FFTOOL_MODELS"
KINDS = ("goal", "cvae", "dlow")  # what a profile's run trains, upstream first
INDEX = "index.json"  # models/<profile>/index.json: every shipped model's manifest sha256, written by pack and rekey
NAME = re.compile(r"(?P<profile>[a-z0-9_]+)/(?P<benchmark>[A-Za-z0-9_.-]+)/(?P<variant>[a-z]+)")


def _installed_models() -> Path | None:
    """The models/ folder of the installed `fftool-models` wheel (tools/build_wheels.py), if there is one."""
    if importlib.util.find_spec("fftool_models") is None:
        return None
    from fftool_models import MODELS

    return MODELS


def models_root() -> Path:
    """`$FFTOOL_MODELS`; else the `models/` folder of the source checkout fftool runs from; else that of the
    installed `fftool-models` wheel."""
    if ENV_MODELS in os.environ:
        return Path(os.environ[ENV_MODELS])
    checkout = Path(__file__).resolve().parents[2]
    installed = _installed_models()
    return checkout / "models" if (checkout / "pyproject.toml").is_file() or installed is None else installed


def models_version() -> str:
    """Which models fftool uses, for `fftool --version`: the installed wheel's version, or the folder."""
    root = models_root()
    if root == _installed_models():
        return f"fftool-models {importlib.metadata.version('fftool-models')} ({root})"
    return f"{root}" + ("" if root.is_dir() else " (not there: no shipped models)")


def pipelines_root() -> Path:
    """The profiles the shipped models are checked against: `pipelines/` beside the models folder."""
    return models_root().parent / "pipelines"


def is_name(ref: str | Path) -> bool:
    """Whether `ref` reads as a shipped model's name (`cpu/zara1/dr`) rather than an artifact id or folder."""
    return isinstance(ref, str) and NAME.fullmatch(ref) is not None and not Path(ref).exists()


@dataclass(frozen=True)
class Shipped:
    """One shipped artifact and what it is: its profile, benchmark, stage and (for cvae and dlow) variant."""

    profile: str
    artifact: Artifact

    @property
    def kind(self) -> str:
        return self.artifact.kind

    @property
    def benchmark(self) -> str:
        return str(self.artifact.manifest.params["benchmark"])

    @property
    def variant(self) -> str | None:
        manifest = self.artifact.manifest
        return manifest.params.get("variant") or manifest.stats.get("variant")

    @property
    def name(self) -> str:
        """`cpu/zara1/dr` for a CVAE, `cpu/zara1/dr/dlow` for its DLow sampler, `cpu/zara1/goal-unet`."""
        base = f"{self.profile}/{self.benchmark}"
        return {"goal": f"{base}/goal-unet", "cvae": f"{base}/{self.variant}", "dlow": f"{base}/{self.variant}/dlow"}[
            self.kind
        ]

    def profile_config(self) -> PipelineConfig:
        return profile_config(self.profile)

    def expected_fingerprint(self, cfg: PipelineConfig | None = None) -> str:
        """The fingerprint today's code computes for this stage, benchmark and variant under the profile."""
        cfg = cfg or self.profile_config()
        return planned(cfg, self.kind, self.variant, self.benchmark, self.recorded_data(cfg)).fingerprint

    def recorded_data(self, cfg: PipelineConfig) -> dict[str, dict[str, str]]:
        """The raw-file hashes its lineage recorded, for the stages whose data folder is not here: a user without
        the benchmark data (an installed fftool) can still tell a current model from one the code no longer
        computes. Where the folder is here, its files are hashed, so a model of other data is never current."""
        folders = {"tracks": cfg.data.raw_dir, "maps": cfg.data.scenes_dir}
        recorded = self.artifact.manifest.stats.get("lineage", {})
        return {
            stage: dict(recorded[stage]["raw"])
            for stage, folder in folders.items()
            if stage in recorded and not cfg.data.dataset and not Path(folder).is_dir()
        }


def chain(
    cfg: PipelineConfig,
    kind: str,
    variant: str | None,
    benchmark: str,
    recorded: dict[str, dict[str, str]] | None = None,
) -> dict[str, Resolved]:
    """Every build `reproduce` plans up to one trained stage (of a variant's CVAE, for cvae and dlow), by stage;
    `recorded`: raw-file hashes standing in for data that is not here (`Shipped.recorded_data`)."""
    from fftool import pipeline

    chosen = cfg if variant is None else predictor_config(cfg, variant)
    return {item.stage.name: item for item in pipeline.resolve(chosen, [kind], benchmark, recorded)}


def planned(
    cfg: PipelineConfig,
    kind: str,
    variant: str | None,
    benchmark: str,
    recorded: dict[str, dict[str, str]] | None = None,
) -> Resolved:
    """The build `reproduce` plans for one trained stage."""
    return chain(cfg, kind, variant, benchmark, recorded)[kind]


def profile_config(profile: str) -> PipelineConfig:
    path = pipelines_root() / f"{profile}.toml"
    if not path.is_file():
        raise UsageError(f"models/{profile}: no profile {path} to check its models against")
    return load_config(path)


def store(profile: str, root: Path | None = None) -> ArtifactStore:
    folder = (root or models_root()) / profile
    if not folder.is_dir():
        raise UsageError(
            f"no shipped models for profile {profile!r} (looked in {folder}); install the fftool-models wheel "
            f"(docs/models.md), or name a models/ folder with ${ENV_MODELS}"
        )
    return ArtifactStore(folder)


def profiles(root: Path | None = None) -> list[str]:
    """The profiles with shipped models; none is a UsageError naming where fftool looked."""
    folder = root or models_root()
    found = sorted(p.name for p in folder.iterdir() if (p / INDEX).is_file()) if folder.is_dir() else []
    if not found:
        raise UsageError(
            f"no shipped models in {folder} (no models/<profile>/{INDEX}; ${ENV_MODELS} names the models/ folder "
            "of an fftool checkout when fftool is installed from elsewhere)"
        )
    return found


def shipped(profile: str, benchmarks: Iterable[str] | None = None, root: Path | None = None) -> list[Shipped]:
    """The profile's shipped artifacts (of the benchmarks given), in KINDS order, then by benchmark and variant.

    Every model folder must be the one the zoo's index names, its manifest byte for byte as packed: a folder
    the index does not know, a manifest edited or damaged, a model the index names but the folder lacks, and
    two models under one name are each an IntegrityError, wherever the zoo is read (list, install, load)."""
    zoo = store(profile, root)
    index = read_index(zoo.root)
    found, seen = [], set()
    for folder in sorted(f for kind in KINDS if (zoo.root / kind).is_dir() for f in (zoo.root / kind).iterdir()):
        ref = f"{folder.parent.name}/{folder.name}"
        seen.add(ref)
        if ref not in index:
            raise IntegrityError(f"{folder}: not in the zoo's index {zoo.root / INDEX}, so not a model fftool packed")
        manifest = folder / MANIFEST
        if folder.is_symlink() or not manifest.is_file() or sha256_file(manifest) != index[ref]:
            raise IntegrityError(f"{folder}: its manifest is not the one packed (git checkout it, or pack it again)")
        found.append(Shipped(profile, zoo.read(folder)))
    missing = sorted(set(index) - seen)
    if missing:
        raise IntegrityError(f"{zoo.root}: the index names {missing[0]}, which is not there (git checkout it)")
    names = [m.name for m in found]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise IntegrityError(f"{zoo.root}: two shipped models named {twice[0]}; the zoo holds one model per name")
    chosen = None if benchmarks is None else set(benchmarks)
    found = [m for m in found if chosen is None or m.benchmark in chosen]
    return sorted(found, key=lambda m: (KINDS.index(m.kind), m.benchmark, m.variant or ""))


def read_index(folder: Path) -> dict[str, str]:
    """artifact id -> sha256 of its manifest.json, as `pack` and `rekey` left them."""
    try:
        index = json.loads((folder / INDEX).read_text())["models"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise IntegrityError(f"{folder / INDEX}: not a readable zoo index ({exc}); git checkout it") from None
    if not isinstance(index, dict):
        raise IntegrityError(f"{folder / INDEX}: not a readable zoo index; git checkout it")
    return index


def write_index(zoo: ArtifactStore) -> None:
    """The index of every model folder the zoo holds now (called by the commands that change it)."""
    models = {
        f"{folder.parent.name}/{folder.name}": sha256_file(folder / MANIFEST)
        for kind in KINDS
        if (zoo.root / kind).is_dir()
        for folder in sorted((zoo.root / kind).iterdir())
    }
    with replacing_file(zoo.root / INDEX) as partial:
        partial.write_text(json.dumps({"models": models}, indent=1, sort_keys=True) + "\n")


def orphans(models: Iterable[Shipped]) -> dict[str, str]:
    """Shipped models whose fingerprint the code no longer computes: name -> one line saying what to do."""
    configs: dict[str, PipelineConfig] = {}
    lines = {}
    for model in models:
        cfg = configs.setdefault(model.profile, model.profile_config())
        expected, profile_file = model.expected_fingerprint(cfg), f"pipelines/{model.profile}.toml"
        if expected != model.artifact.fingerprint:
            lines[model.name] = (
                f"{model.name} ({model.artifact.id}) was trained under a fingerprint the code no longer computes "
                f"({model.kind}/{expected[:16]} now): a change to {profile_file} or to the {model.kind} stage (or "
                f"upstream) alters what it is. Retrain it (`fftool reproduce {profile_file} --benchmarks "
                f"{model.benchmark}`, then `fftool models pack`), or, if the change leaves the model as it was, "
                "re-key it (`fftool models rekey`)"
            )
    return lines


def check(model: Shipped, zoo: ArtifactStore) -> None:
    """Refuse a shipped model whose files changed since it was trained or whose schema this code cannot read."""
    check_schema(model.artifact, model.kind)
    problems = zoo.verify(model.artifact)
    if problems:
        raise IntegrityError(f"{model.artifact.path}: {problems[0]}; the shipped model is damaged (git checkout it)")


@dataclass(frozen=True)
class Bundle:
    """What a shipped name loads: the CVAE, the DLow sampler the profile evaluates it with, the goal U-Net."""

    cvae: Artifact
    dlow: Artifact | None
    goal: Artifact | None
    store: ArtifactStore  # the profile's shipped models
    fair_code: FairCode  # the code each goal decodes with under the fair protocol (evaluate.fair_code)


def find(name: str, root: Path | None = None) -> Bundle:
    """The CVAE named `<profile>/<benchmark>/<variant>`, its DLow sampler (when the profile keeps one) and, for
    variants that read a goal, its benchmark's goal U-Net; every file checked against its manifest."""
    match = NAME.fullmatch(name)
    if match is None:
        raise UsageError(f"{name!r}: expected a shipped model's name, <profile>/<benchmark>/<variant> (cpu/zara1/dr)")
    profile, benchmark, variant = match["profile"], match["benchmark"], match["variant"]
    if variant not in VARIANTS:
        raise UsageError(f"{name}: unknown variant {variant!r}; one of {', '.join(VARIANTS)}")
    zoo = store(profile, root)
    models = shipped(profile, [benchmark], root)
    by_kind = {m.kind: m for m in models if m.variant in (variant, None)}
    if "cvae" not in by_kind:
        names = ", ".join(m.name for m in models if m.kind == "cvae") or "none"
        raise FftoolError(f"no shipped model {name} (shipped for {benchmark}: {names}; see `fftool models list`)")
    for model in by_kind.values():
        check(model, zoo)
    cvae = by_kind["cvae"].artifact
    dlow = by_kind.get("dlow")
    if variant in profile_config(profile).dlow.variants and (
        dlow is None or dlow.artifact.manifest.sources.get("cvae") != cvae.fingerprint
    ):  # the profile draws this variant through a sampler: never fall back to the prior's draws
        raise IntegrityError(f"{name}: its profile draws it through a DLow sampler, and no shipped sampler is its own")
    goal = by_kind.get("goal") if reads_goal(variant) else None
    if reads_goal(variant) and goal is None:
        raise IntegrityError(f"{name}: a goal variant, and its benchmark's goal U-Net is not shipped")
    evaluate = variant_section(predictor_config(profile_config(profile), variant), "evaluate")
    assert isinstance(evaluate, EvaluateConfig)
    return Bundle(cvae, dlow.artifact if dlow else None, goal.artifact if goal else None, zoo, evaluate.fair_code)


def install(target: ArtifactStore, models: Iterable[Shipped], root: Path | None = None) -> list[tuple[Shipped, str]]:
    """Copy current shipped models into `target` (each file checked, the copy checked again, atomically); the
    status of each: installed, or present (the store had it). An orphaned or damaged model stops the install
    before anything is copied."""
    models = list(models)
    stale = list(orphans(models).values())
    if stale:
        more = f" (and {len(stale) - 1} more)" if len(stale) > 1 else ""
        raise FftoolError(stale[0] + more)
    zoos = {profile: store(profile, root) for profile in {m.profile for m in models}}
    for model in models:
        check(model, zoos[model.profile])
    done = []
    for model in models:
        existing = target.lookup(model.kind, model.artifact.fingerprint)
        if existing is not None:
            target.check_inputs({model.kind: existing})
            done.append((model, "present"))
        else:
            target.adopt(model.artifact)
            done.append((model, "installed"))
    return done


def trained_by(cfg: PipelineConfig, benchmark: str) -> list[tuple[str, str | None, str]]:
    """(kind, variant, fingerprint) of every model the profile trains for a benchmark: the goal U-Net, the
    CVAEs of the baseline and report.variants, the DLow samplers of dlow.variants."""
    variants = ["baseline", *(v for v in cfg.report.variants if v != "baseline")]
    wanted: list[tuple[str, str | None]] = [("goal", None), *(("cvae", v) for v in variants)]
    wanted += [("dlow", v) for v in variants if v in cfg.dlow.variants]
    return [(kind, variant, planned(cfg, kind, variant, benchmark).fingerprint) for kind, variant in wanted]


def lineage(builds: dict[str, Resolved], kind: str) -> dict[str, Any]:
    """What a trained model was built from, stage by stage upstream of it (`chain`'s builds): each stage's
    parameters and the raw files it hashed (not the code versions, which a re-key may change). Kept in the
    shipped manifest's stats, so a re-key can tell a code change from a change of the training inputs."""
    found = {
        name: {"params": item.params, "raw": {k: v for k, v in item.inputs.items() if k.split("[")[0] not in builds}}
        for name, item in builds.items()
        if name != kind
    }
    return json.loads(json.dumps(found))  # as the manifest will hold it


def pack(source: ArtifactStore, profile: str, benchmarks: Iterable[str], root: Path | None = None) -> list[str]:
    """Copy a benchmark's trained models from `source` into `models/<profile>/` (all of them or nothing), each
    with its lineage, and remove the shipped models of those benchmarks they replace (the same name, another
    fingerprint) or the profile no longer trains (a sampler it dropped); the names packed."""
    cfg = profile_config(profile)
    chosen = list(benchmarks)
    plan = []
    for benchmark in chosen:
        for kind, variant, fp in trained_by(cfg, benchmark):
            artifact = source.lookup(kind, fp)
            if artifact is None:
                what = f"{kind} {variant or ''}".strip()
                raise FftoolError(
                    f"{source.root} has no {what} model of {benchmark} for pipelines/{profile}.toml; train it first "
                    f"(`fftool reproduce pipelines/{profile}.toml --benchmarks {benchmark}`)"
                )
            source.check_inputs({kind: artifact})
            stats = artifact.manifest.stats | {"lineage": lineage(chain(cfg, kind, variant, benchmark), kind)}
            plan.append((artifact, replace(artifact.manifest, stats=stats)))
    folder = (root or models_root()) / profile  # made only once every model is found: a failed pack leaves nothing
    folder.mkdir(parents=True, exist_ok=True)
    zoo = ArtifactStore(folder)
    if not (folder / INDEX).exists():
        write_index(zoo)  # a new zoo
    old = {m.name: m for m in shipped(profile, chosen, root)}
    packed = []
    for artifact, manifest in plan:
        kept = next((m for m in old.values() if m.artifact.fingerprint == artifact.fingerprint), None)
        if kept is not None:  # shipped already: left as it is, with what `validate` recorded
            packed.append(kept.name)
            continue
        model = Shipped(profile, zoo.adopt(artifact, manifest))
        replaced = old.get(model.name)
        if replaced is not None:
            zoo.remove(replaced.artifact)
        packed.append(model.name)
    for name in old.keys() - set(packed):
        zoo.remove(old[name].artifact)
    write_index(zoo)
    return packed


def shipped_goals(source: ArtifactStore, profile: str, benchmark: str) -> Artifact:
    """The goals artifact the profile's shipped goal U-Net drew for `benchmark`, as `source` holds it."""
    goals = source.lookup("goals", chain(profile_config(profile), "goals", None, benchmark)["goals"].fingerprint)
    if goals is None:
        raise FftoolError(
            f"{source.root} has no goals of {benchmark} for pipelines/{profile}.toml; draw them first "
            f"(`fftool sample-goals --benchmarks {benchmark} -c pipelines/{profile}.toml`)"
        )
    return goals


def validate(source: ArtifactStore, profile: str, benchmarks: Iterable[str], root: Path | None = None) -> list[str]:
    """Score every shipped model that reads a goal (its CVAE, and its DLow sampler) under the fair protocol on
    its validation windows, with the goals the profile's shipped goal U-Net draws (`learning/fair_validation`;
    a CVAE with the code its profile decodes goals with, a DLow sampler with its own codes),
    and record the numbers in its manifest's stats (`fair_validation`); the names scored. `source` holds the
    windows, forces and goals artifacts the profile builds (`fftool reproduce` or `fftool sample-goals`)."""
    import torch

    from fftool.learning.fair_validation import fair_validation

    cfg, zoo, done = profile_config(profile), store(profile, root), []
    for benchmark in benchmarks:
        models = [m for m in shipped(profile, [benchmark], root) if m.variant is not None and reads_goal(m.variant)]
        if not models:
            continue
        goals = shipped_goals(source, profile, benchmark)
        cvaes = {m.variant: m for m in models if m.kind == "cvae"}
        for model in models:
            check(model, zoo)
            cvae = cvaes[model.variant].artifact if model.kind == "dlow" else model.artifact
            dlow = model.artifact if model.kind == "dlow" else None
            evaluate = variant_section(predictor_config(cfg, model.variant), "evaluate")
            assert isinstance(evaluate, EvaluateConfig)
            code = evaluate.fair_code if dlow is None else "prior"  # a sampler is scored with its own codes
            found = fair_validation(source, goals, cvae, dlow, torch.device("cpu"), code)
            manifest = model.artifact.manifest
            zoo.replace_manifest(model.artifact, replace(manifest, stats=manifest.stats | {"fair_validation": found}))
            write_index(zoo)  # the zoo stays whole between models: the next benchmark's `shipped` reads it all
            done.append(model.name)
    return done


def fair_numbers(model: Shipped, goal_unets: Iterable[Shipped]) -> dict[str, Any] | None:
    """The model's recorded fair validation, if it was scored with the goals of the goal U-Net shipped beside it."""
    found = model.artifact.manifest.stats.get("fair_validation")
    current = {m.artifact.fingerprint for m in goal_unets if m.kind == "goal" and m.benchmark == model.benchmark}
    return found if found and found.get("goal_unet") in current else None


# Options removed from the code, with the one behaviour that stayed: a model recorded with that value was trained
# as today's code trains; one recorded with another value was not, and is refused. (DLow's fixed diversity
# weight, scale and schedule were recorded at their defaults and read only with per_benchmark = "fixed".)
RETIRED: dict[str, object] = {
    "dlow.per_benchmark": "agentformer",
    "dlow.warmup_fraction": 0.0,
    "dlow.diverse_weight": 5.0,
    "dlow.d_scale": 5.0,
    "dlow.schedule": "step",
}


def _qualified(section: str | None, key: str) -> str:
    return key if "." in key or section is None else f"{section}.{key}"


def _default(section: str | None, key: str) -> object:
    """The default of a record's key: a bare key is `section`'s, a dotted one names its section."""
    name, _, bare = key.rpartition(".")
    owner = name or section
    if owner is None:
        return None
    return type(getattr(PipelineConfig(), owner))().model_dump(mode="json").get(bare)


def _changed(today: dict[str, Any], recorded: dict[str, Any], section: str | None) -> list[str]:
    """The keys whose values differ, but for keys the record lacks that today holds at their default (an
    option added since, whose default is the behaviour the model was trained with) and keys today lacks that
    the record holds at the behaviour kept when they were retired (`RETIRED`)."""
    added = {k for k in today if k not in recorded and today[k] == _default(section, k)}
    retired = {k for k in recorded if k not in today and RETIRED.get(_qualified(section, k), ...) == recorded[k]}
    return sorted(k for k in {*today, *recorded} - added - retired if today.get(k) != recorded.get(k))


def _lineage_changes(today: dict[str, Any], recorded: dict[str, Any]) -> list[str]:
    """`stage.key` of every parameter or raw file upstream of a model that is not what it was trained on."""
    from fftool import pipeline

    changes = []
    for name in sorted({*today, *recorded}):
        now, then = today.get(name, {"params": {}, "raw": {}}), recorded.get(name, {"params": {}, "raw": {}})
        section = pipeline.STAGES[name].section if name in pipeline.STAGES else None
        changes += [f"{name}.{k}" for k in _changed(now["params"], then["params"], section)]
        changes += [
            f"{name} file {k}" for k in sorted({*now["raw"], *then["raw"]}) if now["raw"].get(k) != then["raw"].get(k)
        ]
    return changes


def rekey(profile: str, benchmarks: Iterable[str] | None = None, root: Path | None = None) -> list[str]:
    """Move orphaned shipped models to the fingerprints the code computes now, when only code versions
    changed, or options were added that the profile leaves at their defaults (a new option's default is the
    behaviour the model was trained with). A model whose own parameters, or whose lineage (every upstream
    stage's parameters and raw files, recorded when it was packed), differ from today's otherwise is refused:
    it was trained on something else, retrain it. A current model packed without a lineage gets today's, which
    its fingerprint proves is its own. The manifest's fingerprint, params, inputs and sources are rewritten and
    `rekeyed_from` is added to its stats; the names re-keyed."""
    cfg = profile_config(profile)
    zoo = store(profile, root)
    moved: list[str] = []
    renamed: dict[str, str] = {}  # old fingerprint -> new, of the models re-keyed
    for model in shipped(profile, benchmarks, root):
        builds = chain(cfg, model.kind, model.variant, model.benchmark)
        item, manifest = builds[model.kind], model.artifact.manifest
        today = lineage(builds, model.kind)
        if item.fingerprint == manifest.fingerprint:
            if "lineage" not in manifest.stats:
                check(model, zoo)
                zoo.replace_manifest(model.artifact, replace(manifest, stats=manifest.stats | {"lineage": today}))
            continue
        if "lineage" not in manifest.stats:
            raise FftoolError(
                f"{model.name}: packed without a lineage, so a re-key cannot tell a code change from other training "
                "inputs; retrain it"
            )
        changed = _changed(item.params, manifest.params, item.stage.section)
        changed += _lineage_changes(today, manifest.stats["lineage"])
        if changed:
            raise FftoolError(f"{model.name}: trained with other parameters ({', '.join(changed)}); retrain it")
        check(model, zoo)
        stats = manifest.stats | {"rekeyed_from": manifest.fingerprint, "lineage": today}
        new = replace(
            manifest,
            fingerprint=item.fingerprint,
            params=item.params,
            inputs=item.inputs,
            sources=item.sources,
            stats=stats,
        )
        zoo.adopt(model.artifact, new)
        zoo.remove(model.artifact)
        moved.append(model.name)
        renamed[manifest.fingerprint] = item.fingerprint
    write_index(zoo)
    for model in shipped(profile, benchmarks, root):  # fair numbers scored with a goal U-Net re-keyed above
        found = model.artifact.manifest.stats.get("fair_validation")
        if found and found.get("goal_unet") in renamed:
            stats = model.artifact.manifest.stats | {
                "fair_validation": found | {"goal_unet": renamed[found["goal_unet"]]}
            }
            zoo.replace_manifest(model.artifact, replace(model.artifact.manifest, stats=stats))
    write_index(zoo)
    return moved
