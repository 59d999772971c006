"""The examples of every `--help` are executed: each `fftool ...` line after `Example:`/`Examples:` in a
command's epilog (or a group's help) runs here through the real CLI, on the tiny synthetic dataset, or is
listed in `NOT_RUN` with the reason. docs/cli.md shows the same text (tools/gen_cli_docs.py).

How an example maps to a run:

- The examples are read from the Typer app (`fftool.cli.app`), not from docs/cli.md: every command's
  epilog and help, from the first line starting with `Example:` or `Examples:`; an example is a line that
  starts with `fftool ` there, with a trailing `# comment` removed. An example shared by two commands
  (`reproduce` and `ablate` show the same ones) runs once.
- A `torchrun ... -m fftool ...` line (a data-parallel run) is an example too.
- They all run in ONE checkout (`make_checkout` of tests/doc_fixtures.py, as the doc tests use): the
  synthetic raw tree at `../shared/data/eth_ucy/raw` (the default `data.raw_dir`), a scene for zara1, and
  `pipelines/quick.toml` = the tiny profile under the quick profile's name, with the real quick
  profile's `report.variants` (goal, dr, re), so that `fftool reproduce pipelines/quick.toml` trains the
  models the `plot` examples draw, as it does for a user; `pipelines/cpu.toml` = the tiny one again,
  whose models the `fftool models` examples ship into the checkout's `models/` (`$FFTOOL_MODELS`). Each
  example runs as written with bash in that folder, `fftool` of this Python first on PATH and
  `$FFTOOL_ARTIFACTS` unset.
- Order: commands in the order of `ORDER` below (a pipeline's order: data first, then each stage,
  reports, then the commands that read what those built); within a command, the epilog's order. A
  command with examples that `ORDER` lacks fails `test_every_command_with_examples_is_ordered`.
- Substituted: an example naming one artifact by id (`evaluate/3f9c2a`) has a placeholder fingerprint;
  `PLACEHOLDERS` says which artifact of the checkout stands in for it (found by its label, the newest
  if several), and the test runs the example with that artifact's real id, as a user would paste the
  id from `fftool artifacts list`.
- Not run: `NOT_RUN` maps an example's text to the reason; such an example is reported as skipped. An
  entry that matches no example fails `test_not_run_and_placeholders_match_examples`, so the list cannot
  outlive the examples it describes.

Selecting one example (`-k rescore`) still runs the examples ordered before it first, as a reader would.
"""

from __future__ import annotations

import re
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import typer.main

from fftool.artifacts.store import ArtifactStore
from fftool.cli import app
from fftool.config import load_config
from tests.doc_fixtures import BLOCK_TIMEOUT_S, ROOT, make_checkout, shell_env, tail

pytestmark = pytest.mark.slow  # every --help example, each a real `fftool` process

# Commands in the order their examples run: each reads what the ones above it built.
ORDER = [
    "fftool fetch-data",  # not run (internet); make_checkout places the synthetic tree where it would
    "fftool",
    "fftool simulate-crowd",  # writes crowd/, which `fftool ingest --dataset crowd/dataset.toml` reads
    "fftool ingest",
    "fftool forces",
    "fftool maps",
    "fftool train-goal",
    "fftool sample-goals",
    "fftool train-cvae",
    "fftool train-dlow",  # over the dr CVAE train-cvae built
    "fftool evaluate",
    "fftool models pack",  # trains the checkout's tiny cpu profile for zara1, then ships it in models/
    "fftool models validate",  # scores the dr that pack shipped, with the goals sample-goals draws
    "fftool models",  # lists what pack shipped
    "fftool models install",
    "fftool models list",
    "fftool models rekey",
    "fftool predict",  # the dr model train-cvae built, a shipped one, and the checkout's tracks.csv and goals.csv
    "fftool export",  # not run (minutes each)
    "fftool reproduce",
    "fftool ablate",
    "fftool plot",
    "fftool rescore",
    "fftool artifacts",
    "fftool artifacts list",
    "fftool artifacts show",
    "fftool artifacts verify",
]

_TORCHRUN = (
    "starts two ranks that each import torch and fftool (half a minute on a 2-core machine); tests/test_ddp.py "
    "runs the same path (pipeline.run with torchrun's environment, 2 gloo ranks) on the tiny data"
)
_EXPORT = (
    "an export traces the 12 unrolled decoding steps (over a minute even for a tiny model); tests/test_export.py "
    "runs `fftool export` on a tiny dr CVAE with its DLow sampler and checks the graph against torch"
)
NOT_RUN = {
    "fftool fetch-data --dest data/eth_ucy/raw": "downloads from the internet; tests/test_fetch.py runs it against "
    "a local server, and the checkout's data/eth_ucy/raw holds the synthetic tree in its place",
    "fftool reproduce pipelines/cpu.toml --benchmarks zara1 --jobs 2": "the cpu profile trains for about 48 minutes "
    "on 2 cores (90 thread-minutes); the "
    "checkout's pipelines/cpu.toml is the tiny profile, which the `fftool models pack` example trains",
    "fftool reproduce pipelines/paper.toml --device cuda": "the full paper configuration needs a GPU and "
    "hours; the test checkout has the quick profile only",
    "fftool export cpu/zara1/dr --out zara1_dr/": _EXPORT,
    "fftool export dlow/8e1b07 --out mine/": _EXPORT,
    "torchrun --standalone --nproc-per-node 2 -m fftool train-goal --config pipelines/quick.toml": _TORCHRUN,
    "torchrun --standalone --nproc-per-node 2 -m fftool train-cvae --variant dr --config pipelines/quick.toml": (
        _TORCHRUN
    ),
}

# Placeholder id in an example -> (kind, label) of the checkout's artifact whose real id replaces it.
PLACEHOLDERS = {
    "evaluate/3f9c2a": ("evaluate", "zara1 · dr · paper"),  # what `fftool evaluate ... --variant dr` built
    "cvae/3f9c2a": ("cvae", "zara1 · dr"),  # what `fftool train-cvae --variant dr` built
}

EXAMPLE_START = re.compile(r"^\s*Examples?:", re.MULTILINE)
COMMENT = re.compile(r"\s+#.*$")


def examples_in(text: str | None) -> list[str]:
    """The `fftool ...` lines after the first `Example:`/`Examples:` of a help text, comments removed."""
    if not text:
        return []
    start = EXAMPLE_START.search(text)
    if not start:
        return []
    found = []
    for line in text[start.start() :].splitlines():
        line = re.sub(r"^\s*Examples?:", "", line).strip()
        if line.startswith(("fftool ", "torchrun ")):  # torchrun ... -m fftool: a data-parallel run
            found.append(COMMENT.sub("", line))
    return found


def collect() -> dict[str, list[str]]:
    """Command name ("fftool artifacts show") -> its examples, for every command and group that has some."""
    commands: dict[str, list[str]] = {}

    def walk(command, name: str) -> None:
        examples = examples_in(command.help) + examples_in(command.epilog)
        if examples:
            commands[name] = examples
        for sub_name, sub in getattr(command, "commands", {}).items():
            walk(sub, f"{name} {sub_name}")

    walk(typer.main.get_command(app), "fftool")
    return commands


COMMANDS = collect()


def ordered_examples() -> list[str]:
    """Every example once, in ORDER's order of commands (unordered commands last: their test fails)."""
    rank = {name: i for i, name in enumerate(ORDER)}
    seen: dict[str, None] = {}
    for name in sorted(COMMANDS, key=lambda n: rank.get(n, len(ORDER))):
        for example in COMMANDS[name]:
            seen.setdefault(example)
    return list(seen)


EXAMPLES = ordered_examples()


@dataclass
class ExampleRun:
    """The examples run in order in one checkout, like one terminal session."""

    checkout: Path
    outcomes: list[tuple[str, str]] = field(default_factory=list)  # (passed|skipped|failed, message)

    def run_through(self, index: int) -> None:
        __tracebackhide__ = True
        for i in range(len(self.outcomes), index + 1):
            self.outcomes.append(self._run(EXAMPLES[i]))
        status, message = self.outcomes[index]
        if status == "skipped":
            pytest.skip(message)
        if status == "failed":
            earlier = [EXAMPLES[i] for i in range(index) if self.outcomes[i][0] == "failed"]
            raise AssertionError(message + (f"\n(earlier examples failed too: {earlier})" if earlier else ""))

    def _run(self, example: str) -> tuple[str, str]:
        if example in NOT_RUN:
            return "skipped", f"not run: {NOT_RUN[example]}"
        command = example
        for placeholder, (kind, label) in PLACEHOLDERS.items():
            if placeholder in command:
                command = command.replace(placeholder, self.real_id(kind, label))
        done = subprocess.run(
            ["bash", "--noprofile", "--norc", "-c", command],
            cwd=self.checkout,
            env=shell_env(self.checkout.parent / "shell_state.sh", self.checkout),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            timeout=BLOCK_TIMEOUT_S,
        )
        if done.returncode != 0:
            ran = f"\n(run as: {command})" if command != example else ""
            return "failed", f"exit status {done.returncode} from {example}{ran}\n{tail(done.stdout)}"
        return "passed", ""

    def real_id(self, kind: str, label: str) -> str:
        matches = [a for a in ArtifactStore(self.checkout / "artifacts").list(kind) if a.label == label]
        if not matches:
            return f"{kind}/no-{kind}-labelled-{label.replace(' ', '')}"  # the command then fails, naming it
        return matches[-1].id  # the newest


def checkout_with_quick_report(base: Path) -> Path:
    """make_checkout's checkout, its tiny quick.toml reporting the real quick profile's variants."""
    checkout = make_checkout(base)
    profile = checkout / "pipelines" / "quick.toml"
    variants = list(load_config(ROOT / "pipelines" / "quick.toml", []).report.variants)
    tiny = profile.read_text()
    assert tiny.count('variants = ["dr"]') == 1, tiny
    profile.write_text(tiny.replace('variants = ["dr"]', f"variants = {variants!r}".replace("'", '"')))
    return checkout


@pytest.fixture(scope="module")
def example_run(tmp_path_factory: pytest.TempPathFactory) -> ExampleRun:
    return ExampleRun(checkout_with_quick_report(tmp_path_factory.mktemp("help_examples")))


@pytest.mark.timeout(1200)  # alone, it runs the examples ordered before it first
@pytest.mark.parametrize("index", range(len(EXAMPLES)), ids=EXAMPLES)
def test_help_example(example_run: ExampleRun, index: int) -> None:
    __tracebackhide__ = True
    example_run.run_through(index)


def test_every_command_with_examples_is_ordered() -> None:
    assert EXAMPLES, "no examples found in any --help"
    missing = sorted(set(COMMANDS) - set(ORDER))
    assert not missing, f"commands with --help examples that ORDER in {__file__} does not place: {missing}"


def test_not_run_and_placeholders_match_examples() -> None:
    stale = [text for text in NOT_RUN if text not in EXAMPLES]
    assert not stale, f"NOT_RUN entries that match no --help example any more: {stale}"
    unused = [p for p in PLACEHOLDERS if not any(p in e for e in EXAMPLES if e not in NOT_RUN)]
    assert not unused, f"PLACEHOLDERS that no run example uses any more: {unused}"


def test_examples_are_read_from_help_texts() -> None:
    text = "Does X.\n\nExamples:\n\n  fftool a --b 1   # note\n\n  not a command\n\n  fftool c"
    assert examples_in(text) == ["fftool a --b 1", "fftool c"]
    assert examples_in("Example: fftool d x   # why") == ["fftool d x"]
    assert examples_in("fftool e, but no example marker") == []
    assert examples_in("Example: torchrun --nproc-per-node 2 -m fftool f") == [
        "torchrun --nproc-per-node 2 -m fftool f"
    ]
