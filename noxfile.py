"""Sessions: main (the README's end-to-end job), tests, dev, lint, bench. Run `python3 -m nox -l` to list.

Every session installs fftool with `-c constraints.txt`, so the versions are the tested ones.
"""

from __future__ import annotations

import os
from pathlib import Path

import nox

nox.options.sessions = ["tests"]
nox.options.reuse_existing_virtualenvs = True

SHARED_RAW = Path("../shared/data/eth_ucy/raw")
CONSTRAINTS = ("-c", "constraints.txt")


@nox.session
def main(session: nox.Session) -> None:
    """The end-to-end job on the real data: `fftool reproduce pipelines/quick.toml --benchmarks zara1`.

    Fetches the raw files if they are not beside the checkout, then runs the whole DAG (ingest, forces,
    maps, goal U-Net and goal samples, the four CVAE variants, evaluation) and writes Tables II-IV.
    """
    session.install(*CONSTRAINTS, "-e", ".")
    raw = SHARED_RAW
    if not raw.is_dir():
        raw = Path("data/eth_ucy/raw")
        session.run("fftool", "fetch-data", "--dest", str(raw))
    session.run(
        "fftool", "reproduce", "pipelines/quick.toml", "--benchmarks", "zara1", "--set", f"data.raw_dir={str(raw)!r}"
    )
    session.log(f"fftool stays installed here: `source {session.bin}/activate`, then `fftool --help`")


@nox.session
def dev(session: nox.Session) -> None:
    """A development environment in .venv (fftool editable, test and lint tools): `source .venv/bin/activate`."""
    session.run("python", "-m", "venv", ".venv", external=True)
    session.run(".venv/bin/python", "-m", "pip", "install", "-q", *CONSTRAINTS, "-e", ".[dev]", external=True)
    session.log("ready: `source .venv/bin/activate`, then `fftool --help` and `pytest`")


@nox.session
def tests(session: nox.Session) -> None:
    """The test suite (CI runs this), in one worker process per core (pytest-xdist, one test file per worker at a
    time, one torch thread each: two torch processes at a thread per core each ran 10-100× slower), listing its
    25 slowest tests. The fast lane: `python3 -m nox -s tests -- -m "not slow"`. With CI set, missing real data
    fails instead of skipping."""
    session.install(*CONSTRAINTS, "-e", ".[test]")
    env = {"OMP_NUM_THREADS": "1"} | ({"FFTOOL_REQUIRE_DATA": "1"} if os.environ.get("CI") else {})
    workers = str(max(1, min(4, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1)))
    session.run("pytest", "-n", workers, "--dist", "loadfile", "--durations=25", *session.posargs, env=env)


@nox.session
def lint(session: nox.Session) -> None:
    """ruff (lint + format check) and the generated CLI reference being current."""
    session.install(*CONSTRAINTS, "-e", ".", "ruff")
    session.run("ruff", "check", "src", "tests", "tools", "benchmarks", "noxfile.py")
    session.run("ruff", "format", "--check", "src", "tests", "tools", "benchmarks", "noxfile.py")
    session.run("python", "tools/gen_cli_docs.py", "--check")


@nox.session
def bench(session: nox.Session) -> None:
    """Benchmarks on the real data: time, peak memory and ratios against plain references."""
    session.install(*CONSTRAINTS, "-e", ".")
    session.run("python", "benchmarks/bench_ingest.py", *session.posargs)
    session.run("python", "benchmarks/bench_forces.py", *session.posargs)
    session.run("python", "benchmarks/bench_cvae.py", "--by-agents", "20")
    session.run("python", "benchmarks/bench_evaluate.py")
    session.run("python", "benchmarks/bench_goal_step.py")


@nox.session
def convergence(session: nox.Session) -> None:
    """Learning curves and time-to-accuracy of CVAE recipes on zara1 (long: see docs/cvae.md for the time)."""
    session.install(*CONSTRAINTS, "-e", ".")
    session.run("python", "benchmarks/bench_convergence.py", *session.posargs)
