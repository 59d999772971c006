"""Docs stay true: the CLI reference is generated from --help, pipeline files load, README has two commands,
and every code block of the executed docs is run or says why not (tests/test_doc_commands.py runs them)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from fftool.config import load_config
from tests.doc_fixtures import DOCS

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

import gen_cli_docs  # noqa: E402

EXECUTED_DOCS = DOCS  # the documents whose code blocks tests/test_doc_commands.py runs
RUN_LANGUAGES = {"bash", "python"}  # the languages tests/test_doc_commands.py runs
TEXT_LANGUAGES = {"text", "toml", "json", "csv", "markdown"}  # shown, never commands


def test_cli_reference_is_current() -> None:
    assert (ROOT / "docs" / "cli.md").read_text() == gen_cli_docs.render(), "run python tools/gen_cli_docs.py"


@pytest.mark.parametrize("path", sorted((ROOT / "pipelines").glob("**/*.toml")), ids=lambda p: p.name)
def test_pipeline_files_load(path: Path) -> None:
    load_config(path)


def test_readme_has_exactly_two_setup_commands() -> None:
    readme = (ROOT / "README.md").read_text()
    setup = readme.split("## Set-up", 1)[1].split("\n## ", 1)[0]
    commands = [line for block in re.findall(r"```bash\n(.*?)```", setup, re.S) for line in block.splitlines()]
    commands = [line for line in commands if line.strip() and not line.lstrip().startswith("#")]
    assert len(commands) == 2
    ci = (ROOT / ".ci" / "run").read_text()
    assert commands[1] in ci, ".ci/run must call the README's test command"


def fences(text: str) -> list[tuple[int, str]]:
    """(line, info string) of each fenced code block's opening fence."""
    opened, found = None, []
    for number, line in enumerate(text.splitlines(), 1):
        fence = re.match(r"\s*(`{3,}|~{3,})(.*)", line)
        if fence and opened is None:
            opened = fence.group(1)
            found.append((number, fence.group(2).strip()))
        elif fence and fence.group(1).startswith(opened) and not fence.group(2).strip():
            opened = None
    return found


@pytest.mark.parametrize("name", EXECUTED_DOCS)
def test_executed_docs_label_every_block(name: str) -> None:
    """A block the doc tests cannot recognise would silently escape them: each says its language."""
    for line, info in fences((ROOT / name).read_text()):  # the whole info string: Sybil matches it exactly
        assert info in RUN_LANGUAGES | TEXT_LANGUAGES, (
            f"{name}:{line}: fenced block labelled {info!r}; use bash or python (run by the doc tests) "
            f"or one of {sorted(TEXT_LANGUAGES)}"
        )


@pytest.mark.parametrize("name", EXECUTED_DOCS)
def test_blocks_not_run_say_why(name: str) -> None:
    """Every skip marker names the one block it skips and gives the reason, for a reader of the source."""
    text = (ROOT / name).read_text()
    markers = re.findall(r"^[ \t]*(<!--\s*skip\b.*?-->)", text, re.S | re.M)  # at a line's start, as Sybil reads them
    for marker in markers:
        assert re.fullmatch(r'<!-- skip: next "[^"]{10,}" -->', marker), (
            f'{name}: {marker!r}: write <!-- skip: next "why this block is not run" -->'
        )


GENERATED_DOCS = sorted(p for p in [ROOT / "README.md", *(ROOT / "docs").rglob("*.md")] if "[[[cog" in p.read_text())


def _cog_check(path: Path) -> int:
    from cogapp import Cog

    return Cog().main(["cog", "--check", "--diff", str(path)])


@pytest.mark.parametrize("path", GENERATED_DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_generated_numbers_agree_with_their_data(path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every table between cog markers is what its CSV renders today: `python -m cogapp -r <page>` rewrites it."""
    monkeypatch.chdir(ROOT)
    assert _cog_check(path) == 0, f"{path.relative_to(ROOT)} disagrees with its data: python -m cogapp -r {path}"


def test_a_number_edited_by_hand_is_caught(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)
    page = next(p for p in GENERATED_DOCS if p.name == "cpu_all.md")
    text = page.read_text()
    generated = text[text.index("]]] -->") : text.index("[[[end]]]")]  # the first generated table
    number = re.search(r"\d\.\d{3}", generated).group()
    edited = tmp_path / page.name
    edited.write_text(text.replace(generated, generated.replace(number, f"{float(number) + 0.001:.3f}", 1)))
    assert _cog_check(edited) != 0


PAGES = sorted([ROOT / "README.md", ROOT / "CHANGELOG.md", *(ROOT / "docs").rglob("*.md")])


def broken_links(page: Path) -> list[str]:
    """Relative link targets of a Markdown page (outside code blocks) that name no file or folder."""
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    targets = (m.group(1).split("#", 1)[0] for m in re.finditer(r"\]\(([^)\s]+)\)", text))
    return [t for t in targets if t and not re.match(r"[a-z]+:", t) and not (page.parent / t).exists()]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_names_a_file_in_the_repository(page: Path) -> None:
    assert broken_links(page) == []


def test_a_link_to_a_missing_file_is_caught(tmp_path: Path) -> None:
    (tmp_path / "here.md").write_text("x")
    page = tmp_path / "page.md"
    page.write_text("[ok](here.md#part) [gone](research/agentformer.md) [web](https://x.org) [anchor](#top)\n")
    assert broken_links(page) == ["research/agentformer.md"]
