"""Executable documentation: Sybil parses the Markdown, these evaluators run its blocks in a user's checkout.

Used by tests/test_doc_commands.py (see its docstring for what runs where). The pieces:

- `parse(path)`: a Sybil `Document` of a Markdown file with three parsers: ```bash blocks (run by
  `BashInCheckout`), ```python blocks (run by `PythonInCheckout`) and Sybil's skip directive
  `<!-- skip: next "reason" -->`, which marks the next block as not run, with the reason.
- `make_checkout(base)`: the folder layout of a user's checkout on the tiny synthetic dataset.
- `DocRun`: one document's blocks, evaluated in order, in one checkout, like one terminal session.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import unittest
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from sybil import Document, Example
from sybil.evaluators.python import PythonEvaluator
from sybil.example import SybilFailure
from sybil.parsers.markdown import CodeBlockParser, SkipParser

from fftool.zoo import ENV_MODELS
from tests.conftest import make_raw_tree
from tests.test_maps import make_scene
from tests.test_reproduce import TINY_PIPELINE

ROOT = Path(__file__).resolve().parents[1]
DOCS = (
    "README.md",
    "docs/tutorial.md",
    "docs/metrics.md",
    "docs/api.md",
)  # every command block in these runs or says why not
FILES_ENV = "FFTOOL_DOC_TEST_FILES"  # os.pathsep-separated Markdown files to test instead (the broken-doc test)
RUN_KEY = "__doc_run__"  # where a document's namespace keeps its DocRun
BLOCK_TIMEOUT_S = 280  # below pytest-timeout's 300 s, so a hung command fails with its output

# What a document's blocks take for granted, run in its checkout before its first block.
GIVEN: dict[str, str] = {
    # `fftool rescore evaluate` and the Python example read an existing evaluation: the cheapest one.
    "docs/metrics.md": "fftool ingest -c pipelines/quick.toml\n"
    "fftool forces -c pipelines/quick.toml\n"
    "fftool evaluate --benchmarks zara1 --variant cv -c pipelines/quick.toml\n",
    # The README's "Use the trained models" and the tutorial's "shipped models first" read the cpu profile's
    # shipped models: the checkout ships tiny ones.
    "README.md": "fftool reproduce pipelines/cpu.toml --benchmarks eth --root ../zoo-training > /dev/null\n"
    "fftool models pack --benchmarks eth --root ../zoo-training\n",
    "docs/tutorial.md": "fftool reproduce pipelines/cpu.toml --benchmarks zara1 --root ../zoo-training > /dev/null\n"
    "fftool models pack --benchmarks zara1 --root ../zoo-training\n",
}

# Set-up commands (install packages, build virtual environments) take minutes and change the machine:
# never run from a doc test. A block with one must carry a skip marker; CI runs the README's (.ci/run).
SETUP_COMMAND = re.compile(r"\bpip\b[^\n]*\binstall\b|\bnox\b")

# Bash for one block: the document's shell variables come in, the block runs with -e and pipefail,
# and the variables it leaves behind go out, so `Q=...` in one block is set in the next.
_BASH_WRAPPER = """\
set -eo pipefail
__doc_known=" $(compgen -v | tr '\\n' ' ') "
if [ -f "$DOC_SHELL_STATE" ]; then source "$DOC_SHELL_STATE"; fi
{block}
for __doc_name in $(compgen -v); do
  case "$__doc_name" in __doc_*|BASH*|PIPESTATUS|_|COLUMNS|LINES|OPTIND|OPTARG) continue ;; esac
  case "$__doc_known" in *" $__doc_name "*) ;; *) declare -p "$__doc_name" ;; esac
done > "$DOC_SHELL_STATE.new"
mv "$DOC_SHELL_STATE.new" "$DOC_SHELL_STATE"
"""


def doc_files() -> list[Path]:
    """The Markdown files under test: `$FFTOOL_DOC_TEST_FILES` if set, else README.md and the docs above."""
    chosen = os.environ.get(FILES_ENV)
    if chosen:
        return [Path(p).resolve() for p in chosen.split(os.pathsep) if p]
    return [ROOT / name for name in DOCS]


def label(path: Path) -> str:
    """A document's name in test ids and messages: relative to the repository when inside it."""
    return path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else path.name


def make_checkout(base: Path) -> Path:
    """A user's checkout on the tiny synthetic dataset; returns the checkout folder (the blocks' cwd).

    base/shared/data/eth_ucy/raw     the synthetic raw tree (tests/conftest.py make_raw_tree), where the
                                     README's layout keeps the real files, beside the checkout
    base/shared/data/eth_ucy/scenes  one scene image + homography for zara1 (tests/test_maps.py make_scene)
    base/checkout/pipelines/quick.toml   the tiny profile (tests/test_reproduce.py TINY_PIPELINE) under the
                                     quick profile's name, reading the two folders above by the same
                                     relative paths as the real pipelines/quick.toml
    base/checkout/pipelines/cpu.toml     the same under the cpu profile's name, with a DLow sampler for the
                                     baseline: the profile of the checkout's shipped models (models/, empty
                                     until a document's GIVEN packs them; FFTOOL_MODELS points there)
    base/checkout/data/eth_ucy/raw   a copy of the synthetic tree: what `fftool fetch-data` would place there
    base/checkout/tracks.csv, goals.csv  a user's own tracks and goals, for `fftool predict` (write_user_tracks)
    """
    shared = base / "shared" / "data" / "eth_ucy"
    make_raw_tree(shared / "raw")
    make_scene(shared / "scenes" / "zara1")
    checkout = base / "checkout"
    (checkout / "pipelines").mkdir(parents=True)
    tiny = TINY_PIPELINE.format(raw="../shared/data/eth_ucy/raw", scenes="../shared/data/eth_ucy/scenes")
    (checkout / "pipelines" / "quick.toml").write_text(tiny)
    (checkout / "pipelines" / "cpu.toml").write_text(tiny.replace("[dlow]\n", '[dlow]\nvariants = ["baseline"]\n'))
    shutil.copytree(shared / "raw", checkout / "data" / "eth_ucy" / "raw")
    write_user_tracks(checkout)
    return checkout


def write_user_tracks(folder: Path) -> None:
    """tracks.csv (two walkers, 10 steps of 0.4 s) and goals.csv (one goal each): a user's files for `predict`."""
    rows = ["time,agent_id,x,y"] + [
        f"{t * 0.4:.1f},{a},{x:.2f},{y:.2f}"
        for a, (x0, y0, vx) in enumerate([(0.0, 0.0, 0.5), (6.0, 1.0, -0.45)], 1)
        for t in range(10)
        for x, y in [(x0 + vx * t, y0)]
    ]
    (folder / "tracks.csv").write_text("\n".join(rows) + "\n")
    (folder / "goals.csv").write_text("agent_id,x,y\n1,11.0,0.0\n2,-4.0,1.0\n")


def shell_env(state_file: Path, checkout: Path) -> dict[str, str]:
    """The environment of a block: this Python's `fftool` first on PATH, the default artifact root, the
    checkout's own shipped models."""
    env = {k: v for k, v in os.environ.items() if k not in ("FFTOOL_ARTIFACTS", "BASH_ENV", "ENV")}
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    env["DOC_SHELL_STATE"] = str(state_file)
    env[ENV_MODELS] = str(checkout / "models")
    return env


@dataclass
class BlockResult:
    returncode: int
    output: str  # stdout and stderr, interleaved


@dataclass
class DocRun:
    """One document's examples, evaluated in document order in one checkout (one terminal session)."""

    path: Path
    document: Document
    checkout: Path
    examples: list[Example] = field(default_factory=list)
    outcomes: dict[int, tuple[str, str]] = field(default_factory=dict)  # index -> (passed|skipped|failed, message)
    outputs: dict[int, str] = field(default_factory=dict)  # line of a bash block -> its output

    def __post_init__(self) -> None:
        self.examples = list(self.document.examples())
        self.document.namespace[RUN_KEY] = self
        self.state_file = self.checkout.parent / "shell_state.sh"
        given = GIVEN.get(label(self.path))
        if given:
            result = self.bash(given)
            assert result.returncode == 0, f"setting up {label(self.path)} failed:\n{given}\n{tail(result.output)}"

    def bash(self, block: str) -> BlockResult:
        script = self.checkout.parent / "block.sh"
        script.write_text(_BASH_WRAPPER.format(block=block))
        done = subprocess.run(
            ["bash", "--noprofile", "--norc", str(script)],
            cwd=self.checkout,
            env=shell_env(self.state_file, self.checkout),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            timeout=BLOCK_TIMEOUT_S,
        )
        return BlockResult(done.returncode, done.stdout)

    def index_of(self, needle: str) -> int:
        """The index of the first code block whose source contains `needle`."""
        for index, example in enumerate(self.examples):
            if is_code_block(example) and needle in str(example.parsed):
                return index
        raise LookupError(f"{label(self.path)}: no code block contains {needle!r}")

    def output_of(self, needle: str) -> str:
        """Run the document down to the bash block containing `needle`; that block's output."""
        index = self.index_of(needle)
        self.run_through(index)
        return self.outputs[self.examples[index].line]

    def run_through(self, index: int) -> None:
        """Evaluate every example up to `index` not evaluated yet, then report example `index`'s outcome.

        Earlier blocks run first even when only one test is selected, because a block relies on the
        ones above it (the data they built, the shell variables they set), as it does for a reader.
        """
        __tracebackhide__ = True
        for i in range(len(self.outcomes), index + 1):
            self.outcomes[i] = self._evaluate(i)
        status, message = self.outcomes[index]
        if status == "skipped":
            pytest.skip(message)
        if status == "failed":
            earlier = [self.examples[i].line for i in range(index) if self.outcomes[i][0] == "failed"]
            note = f"\n(earlier blocks failed too, at lines {earlier})" if earlier else ""
            raise AssertionError(message + note)

    def _evaluate(self, index: int) -> tuple[str, str]:
        example = self.examples[index]
        try:
            example.evaluate()
        except unittest.SkipTest as exc:
            return "skipped", f"{label(self.path)}:{example.line}: not run: {exc}"
        except SybilFailure as exc:  # an evaluator's message: the block and what went wrong
            return "failed", f"{label(self.path)}:{example.line}: {exc.result}"
        except Exception as exc:  # Python code that raised
            return "failed", f"{label(self.path)}:{example.line}: {type(exc).__name__}: {exc}"
        return "passed", ""


def tail(text: str, lines: int = 60) -> str:
    return "\n".join(text.splitlines()[-lines:])


class BashInCheckout:
    """Evaluator of ```bash blocks: the whole block as one bash script (-e, pipefail) in the checkout."""

    def __call__(self, example: Example) -> str | None:
        run: DocRun = example.namespace[RUN_KEY]
        block = str(example.parsed)
        if SETUP_COMMAND.search(block):
            return (
                "this block installs packages or runs nox (minutes, and it changes the machine); the doc "
                'tests never run it: put <!-- skip: next "why it is not run here" --> above it\n' + block
            )
        result = run.bash(block)
        run.outputs[example.line] = result.output
        if result.returncode != 0:
            return f"exit status {result.returncode} from\n{block}--- output (last lines) ---\n{tail(result.output)}"
        return None


class PythonInCheckout:
    """Evaluator of ```python blocks: Sybil's PythonEvaluator, in the document's namespace, cwd = checkout."""

    def __init__(self) -> None:
        self.python = PythonEvaluator()

    def __call__(self, example: Example) -> None:
        run: DocRun = example.namespace[RUN_KEY]
        before = Path.cwd()
        os.chdir(run.checkout)
        try:
            self.python(example)
        finally:
            os.chdir(before)


BASH = CodeBlockParser(language="bash", evaluator=BashInCheckout())
PYTHON = CodeBlockParser(language="python", evaluator=PythonInCheckout())
SKIP = SkipParser()


def parse(path: Path) -> Document:
    """The examples of one Markdown file: bash and python blocks, and skip directives, in order."""
    return Document.parse(str(path), BASH, PYTHON, SKIP)


def is_code_block(example: Example) -> bool:
    return isinstance(example.region.evaluator, BashInCheckout | PythonInCheckout)


def code_blocks(document: Document) -> Iterator[tuple[int, Example]]:
    """(index among all examples, example) of each code block: the directives are not tests of their own."""
    for index, example in enumerate(document.examples()):
        if is_code_block(example):
            yield index, example


def stages_by_cell(output: str) -> dict[str, dict[str, set[str]]]:
    """From a `fftool reproduce` log's plan: for each table cell ("zara1 / re: build …; found …"), the stages
    it builds and those it finds."""
    cells: dict[str, dict[str, set[str]]] = {}
    for line in output.splitlines():
        cell = re.fullmatch(r"\s*\w+ / (\w+): build (.*); found (.*)", line)
        if cell:
            built, found = ({name for name in part.split(", ") if name != "nothing"} for part in cell.group(2, 3))
            cells[cell.group(1)] = {"built": built, "cached": found}
    return cells
