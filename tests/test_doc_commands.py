"""The docs are executed: every ```bash and ```python block of README.md, docs/tutorial.md and docs/metrics.md
runs here through the real CLI, on the tiny synthetic dataset, or is marked in the Markdown as not run.

Tool: Sybil (tests/doc_fixtures.py) parses the Markdown; each code block is one test, in document order.

How a block maps to a run (the substitutions):

- Each document gets a fresh temporary folder laid out like a user's checkout (`make_checkout`):
  `checkout/` is the working folder of every block; `shared/data/eth_ucy/raw` beside it holds the synthetic
  raw tree of tests/conftest.py (`make_raw_tree`) and `shared/data/eth_ucy/scenes/zara1` the synthetic scene
  of tests/test_maps.py (`make_scene`), so the profiles' default `../shared/...` paths work unchanged.
- `pipelines/quick.toml` in that checkout is the tiny profile of tests/test_reproduce.py (`TINY_PIPELINE`:
  1 epoch, 16-wide CVAE, ...) under the quick profile's name: the commands are run exactly as written, with
  tiny sizes.
- `data/eth_ucy/raw` holds a copy of the synthetic tree, standing in for what `fftool fetch-data` places
  there (that block needs the internet and is marked not run; tests/test_fetch.py tests the command).
- A ```bash block runs as one script, `bash -eo pipefail` (a failing line fails the block), with the
  `fftool` of the Python running the tests first on PATH and `$FFTOOL_ARTIFACTS` unset (`./artifacts`).
  The shell variables a block sets reach the next blocks of the same document, as in one terminal.
- A ```python block runs in-process (Sybil's PythonEvaluator) with the checkout as working folder.
- What a document takes for granted is run first (`GIVEN` in tests/doc_fixtures.py): docs/metrics.md's
  blocks read an existing evaluation, so its checkout gets ingest, forces and the cv evaluation.

Not run: a block with `<!-- skip: next "reason" -->` above it (Sybil's skip directive) is reported as
skipped with that reason; tests/test_docs.py checks every such marker gives one. Blocks that install
packages (pip install, nox) are never run and fail until they carry that marker.

Selecting one block (`-k "tutorial.md:60"`) still runs the blocks above it first, as a reader would.
`$FFTOOL_DOC_TEST_FILES` (paths separated by os.pathsep) replaces the documents under test.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from fftool.artifacts.store import ArtifactStore
from tests.doc_fixtures import ROOT, DocRun, code_blocks, doc_files, label, make_checkout, parse, stages_by_cell

pytestmark = pytest.mark.slow  # the docs' commands, each a real `fftool` process

DOCUMENTS = {path: parse(path) for path in doc_files()}
CASES = [
    pytest.param(path, index, id=f"{label(path)}:{example.line}")
    for path, document in DOCUMENTS.items()
    for index, example in code_blocks(document)
]


class _Runs(dict):
    """path -> DocRun, each made (with its checkout) when the document's first block is tested."""

    def __init__(self, tmp_path_factory: pytest.TempPathFactory) -> None:
        super().__init__()
        self.tmp_path_factory = tmp_path_factory

    def __missing__(self, path: Path) -> DocRun:
        base = self.tmp_path_factory.mktemp(path.stem.replace(".", "_"))
        self[path] = DocRun(path, DOCUMENTS[path], make_checkout(base))
        return self[path]


@pytest.fixture(scope="module")
def doc_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[Path, DocRun]:
    return _Runs(tmp_path_factory)


@pytest.mark.parametrize(("path", "index"), CASES)
def test_doc_block(doc_runs: dict[Path, DocRun], path: Path, index: int) -> None:
    __tracebackhide__ = True
    doc_runs[path].run_through(index)


TUTORIAL = ROOT / "docs" / "tutorial.md"
needs_tutorial = pytest.mark.skipif(TUTORIAL not in DOCUMENTS, reason="$FFTOOL_DOC_TEST_FILES leaves the tutorial out")


def table_after(text: str, marker: str) -> dict[str, dict[str, set[str]]]:
    """The first Markdown table after `marker`: cell name -> {"built": ..., "cached": ...} of `names`."""
    rows = text.split(marker, 1)[1].split("\n|", 1)[1].split("\n\n", 1)[0].splitlines()
    table = {}
    for row in rows[2:]:  # after the header and the |---| line
        cell, built, cached = (part.strip() for part in row.strip().strip("|").split("|"))
        table[cell.strip("`")] = {"built": set(_names(built)), "cached": set(_names(cached))}
    return table


def _names(text: str) -> list[str]:
    return [part.split("`")[0] for part in text.split("`")[1::2]] if "`" in text else []


@needs_tutorial
@pytest.mark.timeout(900)  # alone, it runs the tutorial's blocks above it first
def test_tutorial_step6_trains_nothing(doc_runs: dict[Path, DocRun]) -> None:
    """Step 6 finds every model in the store: it only evaluates the cells step 5 did not."""
    cells = stages_by_cell(doc_runs[TUTORIAL].output_of("fftool reproduce --variants goal,dr,re"))
    assert set(cells) == {"cv", "baseline", "goal", "dr", "re"}
    assert {cell: stages["built"] for cell, stages in cells.items()} == {
        "cv": set(),
        "baseline": {"evaluate"},
        "goal": {"evaluate"},
        "dr": set(),  # step 5's paper-protocol evaluation
        "re": {"evaluate"},
    }


@needs_tutorial
@pytest.mark.timeout(900)  # alone, it runs the tutorial's blocks above it first
def test_tutorial_step7_rebuilds_what_its_table_says(doc_runs: dict[Path, DocRun]) -> None:
    """Step 7's table of rebuilt and reused stages is the log of its command, and only F_re changes."""
    run = doc_runs[TUTORIAL]
    logged = stages_by_cell(run.output_of("forces.sigma_m"))
    documented = table_after(TUTORIAL.read_text(), "forces.sigma_m")
    assert logged == documented, f"the log says {logged}"

    artifacts = run.checkout / "artifacts"
    before = pd.read_csv(artifacts / "reports" / "quick" / "results.csv").set_index("variant")
    after = pd.read_csv(artifacts / "reports" / "quick_sigma_0.5" / "results.csv").set_index("variant")
    metrics = ["min_ade", "min_fde", "nc"]
    for unchanged in ("cv", "baseline"):  # they read no force: the same evaluations, so the same numbers
        assert before.loc[unchanged, "artifact"] == after.loc[unchanged, "artifact"]
        assert before.loc[unchanged, metrics].tolist() == after.loc[unchanged, metrics].tolist()
    assert before.loc["re", "artifact"] != after.loc["re", "artifact"]
    store = ArtifactStore(artifacts)
    (changed,) = [a for a in store.list("forces") if a.manifest.params["sigma_m"] == 0.5]  # step 7's
    (before,) = [  # step 2's: the same inputs and constants but sigma (step 9's crowd has other inputs)
        a
        for a in store.list("forces")
        if a.manifest.sources == changed.manifest.sources
        and a.manifest.params == changed.manifest.params | {"sigma_m": a.manifest.params["sigma_m"]}
        and a.manifest.params["sigma_m"] != 0.5
    ]
    f_dr, f_re = ([np.load(a.file(f"{n}.npy")) for a in (before, changed)] for n in ("f_dr", "f_re"))
    assert np.array_equal(*f_dr), "sigma_m changed the driving force"
    assert not np.array_equal(*f_re), "sigma_m did not change the repulsive force"


@needs_tutorial
@pytest.mark.timeout(900)  # alone, it runs the tutorial's blocks above it first
def test_tutorial_step8_keeps_both_sets_of_figures(doc_runs: dict[Path, DocRun]) -> None:
    """Step 8's two plot commands write into two folders, so neither replaces the other's figures."""
    run = doc_runs[TUTORIAL]
    run.run_through(run.index_of("--windows 12,25"))
    for folder in ("most_different", "windows_12_25"):
        written = {p.name for p in (run.checkout / "figures" / folder).iterdir()}
        assert written == {"qualitative_zara1.png", "density_zara1.png"}, folder


BROKEN_DOC = """\
# A page with good, skipped and broken blocks

```bash
fftool --help > /dev/null
WHERE=data/eth_ucy/raw
```

<!-- skip: next "shows that a marked block is not run" -->

```bash
exit 3
```

```bash
test "$WHERE" = data/eth_ucy/raw   # set by the first block
fftool ingest --raw "$WHERE" --no-such-option
```

```python
from pathlib import Path


assert Path("pipelines/quick.toml").is_file()  # run in the checkout
```

```python
assert 1 + 1 == 3, "a broken Python example"
```

```bash
python3 -m pip install -q nox
```
"""


def test_a_broken_doc_command_fails_the_doc_tests(tmp_path: Path) -> None:
    """The same collection on a Markdown file with bad blocks: exactly those fail, each with its error."""
    doc = tmp_path / "broken.md"
    doc.write_text(BROKEN_DOC)
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"{Path(__file__)}::test_doc_block"],
        cwd=ROOT,
        env={**os.environ, "FFTOOL_DOC_TEST_FILES": str(doc)},
        capture_output=True,
        text=True,
        timeout=280,
    )
    assert done.returncode == 1, done.stdout + done.stderr
    assert "3 failed, 2 passed, 1 skipped" in done.stdout, done.stdout
    assert "Error: No such option: --no-such-option" in done.stdout  # the command's own error line
    assert "AssertionError: a broken Python example" in done.stdout
    assert "installs packages or runs nox" in done.stdout
    assert "not run: shows that a marked block is not run" in done.stdout
