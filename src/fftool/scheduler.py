"""The grid engine: every stage build a grid of cells needs, once each, in dependency order.

    cells (configurations) ──resolve──▶ nodes (stage, fingerprint) + edges (sources)
    ready nodes ──submit──▶ executor (this process, a local process pool, or a Dask cluster's) ──▶ the store

Every node a grid needs is one stage build, found once however many cells share it; it is submitted
when everything it reads is in the store, and runs `pipeline.run(..., upstream=False)`, exactly as
`fftool <stage command>` would: in this process with one job (live progress, the first failure stops the
run), else in workers. The artifact store makes concurrent builders safe (atomic installs,
per-fingerprint locks; a killed worker leaves only an `.incomplete/` folder that the next build removes),
so this module only orders work. With workers, a failed build stops the nodes that need it; the others go
on, and the outcome says which failed, why, and which were not built because of it.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from fftool import pipeline
from fftool.artifacts.store import ArtifactStore
from fftool.config import PipelineConfig

Key = tuple[str, str]  # (stage, fingerprint)
LOGS = ".logs"  # under the artifact root: one log per build made by a worker


@dataclass(frozen=True)
class Node:
    """One stage build: a configuration and benchmark that resolve to it, and the builds it reads."""

    stage: str
    fingerprint: str
    cfg: PipelineConfig
    benchmark: str | None
    needs: frozenset[Key]
    label: str  # what the progress bar and messages call it

    @property
    def key(self) -> Key:
        return self.stage, self.fingerprint


@dataclass(frozen=True)
class Plan:
    """Every stage build a grid needs, once each, and each cell's builds (in the order the cells were given)."""

    nodes: dict[Key, Node]
    cells: list[list[Key]]


def plan(cells: Iterable[tuple[PipelineConfig, str]], target: str = "evaluate") -> Plan:
    """Every stage build the cells' `target`s need, once each, with the builds each one reads."""
    nodes: dict[Key, Node] = {}
    per_cell = []
    for cfg, benchmark in cells:
        keys = []
        for item in pipeline.resolve(cfg, [target], benchmark):
            key = (item.stage.name, item.fingerprint)
            needs = frozenset(item.sources.items())
            nodes.setdefault(key, Node(*key, cfg, item.benchmark, needs, item.description))
            keys.append(key)
        per_cell.append(keys)
    return Plan(nodes, per_cell)


@dataclass
class Outcome:
    """What a parallel build did: built (with seconds), failed (with the reason), and not built because a
    build it needs failed (with that build's label)."""

    built: dict[Key, float] = field(default_factory=dict)
    failed: dict[Key, str] = field(default_factory=dict)
    blocked: dict[Key, str] = field(default_factory=dict)


def cores() -> int:
    """CPU cores this process may use (its affinity mask where the platform has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def threads_per_job(jobs: int, threads: int | None = None) -> int:
    """Torch threads for each of `jobs` concurrent builds: `threads` if given, else the cores shared out,
    so jobs × threads never exceeds the cores (two builds with a thread per core each ran 10-100× slower)."""
    return threads if threads else max(1, cores() // jobs)


def log_file(root: Path, node: Node) -> Path:
    """Where a worker's output for `node` goes (appended to, so a retried build keeps the failed try's)."""
    return root / LOGS / f"{node.stage}-{node.fingerprint[:16]}.log"


def build_node(root: str, node: Node, device: str, threads: int | None, to_log: bool = True) -> float:
    """Build one node (in a worker, its output into `<root>/.logs/`; in this process, on the terminal) with
    `threads` torch threads (None: as the process has them); the seconds it took."""
    import torch

    if threads:
        torch.set_num_threads(threads)
    started = time.perf_counter()
    with contextlib.ExitStack() as stack:
        if to_log:  # stdout and stderr (rich's consoles follow them) into the build's log
            log_path = log_file(Path(root), node)
            log_path.parent.mkdir(parents=True, exist_ok=True)
            log = stack.enter_context(open(log_path, "a"))
            stack.enter_context(contextlib.redirect_stdout(log))
            stack.enter_context(contextlib.redirect_stderr(log))
        pipeline.run(
            node.cfg,
            ArtifactStore(Path(root)),
            [node.stage],
            runtime=pipeline.Runtime(device=device),
            upstream=False,
            benchmark=node.benchmark,
        )
    return time.perf_counter() - started


class InlineExecutor(Executor):
    """Runs each submitted build at once in this process: the grid of one job. An exception is kept in its
    future like a worker's; an interrupt (Ctrl-C) is not caught."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        future: Future[Any] = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except Exception as exc:
            future.set_exception(exc)
        return future


def build_all(
    nodes: dict[Key, Node],
    store: ArtifactStore,
    executor: Executor,
    device: str,
    threads: int | None,
    on_event: Callable[[str, Node, str], None] = lambda event, node, detail: None,
) -> Outcome:
    """Build the missing nodes on `executor`, each once its inputs are in the store; in workers, never raises
    for a failed build (see Outcome); in this process (InlineExecutor), the first failure is raised as it
    came. `on_event(event, node, detail)`: "start", "done" (seconds), "failed" (reason)."""
    inline = isinstance(executor, InlineExecutor)
    outcome = Outcome()
    missing = {key for key in nodes if store.lookup(*key) is None}
    running: dict[Future[float], Key] = {}
    while missing or running:
        order = list(pipeline.STAGES)  # upstream stages first: the goal net before the CVAEs and evaluations
        for key in sorted(missing, key=lambda k: (order.index(k[0]), k)):
            node = nodes[key]
            if node.needs & (missing | set(running.values())):
                continue
            missing.discard(key)
            on_event("start", node, "")
            running[executor.submit(build_node, str(store.root), node, device, threads, not inline)] = key
        if not running:  # what is left needs a build that failed
            break
        finished, _ = wait(running, return_when=FIRST_COMPLETED)
        for future in finished:
            key = running.pop(future)
            try:
                outcome.built[key] = future.result()
                on_event("done", nodes[key], f"{outcome.built[key]:.1f} s")
            except Exception as exc:  # a worker's failure is reported, not raised: the others go on
                if inline:  # one job: stop at the first failure, with its own error and exit code
                    raise
                outcome.failed[key] = _one_line(exc)
                on_event("failed", nodes[key], outcome.failed[key])
        _block_dependants(nodes, missing, outcome)
    return outcome


def _block_dependants(nodes: dict[Key, Node], missing: set[Key], outcome: Outcome) -> None:
    """Take the nodes that need a failed (or blocked) build out of `missing`, naming that build."""
    changed = True
    while changed:
        changed = False
        for key in sorted(missing):
            broken = [need for need in nodes[key].needs if need in outcome.failed or need in outcome.blocked]
            if broken:
                missing.discard(key)
                outcome.blocked[key] = nodes[broken[0]].label
                changed = True


def _one_line(exc: BaseException) -> str:
    """fftool's errors as they are (one line already), anything else with its type (a killed worker, a bug)."""
    text = " ".join(str(exc).split())
    return text if type(exc).__module__.startswith("fftool") and text else f"{type(exc).__name__}: {text}"


@contextlib.contextmanager
def local_pool(jobs: int) -> Iterator[Executor]:
    """`jobs` fresh worker processes (spawned: a forked torch process can hang)."""
    with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn")) as pool:
        yield pool


@contextlib.contextmanager
def dask_pool(address: str) -> Iterator[Executor]:
    """The workers of the Dask scheduler at `address` (`pip install 'fftool[cluster]'`); Dask retries a
    build whose worker died (distributed.scheduler.allowed-failures times), then reports it failed."""
    try:
        from distributed import Client
    except ImportError:
        from fftool.errors import UsageError

        raise UsageError("--scheduler needs Dask: pip install 'fftool[cluster]'") from None
    with Client(address) as client:
        yield client.get_executor(pure=False)


@contextlib.contextmanager
def _executor(jobs: int, address: str | None) -> Iterator[Executor]:
    if address:
        with dask_pool(address) as pool:
            yield pool
    elif jobs > 1:
        with local_pool(jobs) as pool:
            yield pool
    else:
        yield InlineExecutor()


def build_grid(
    cells: Iterable[tuple[PipelineConfig, str]],
    store: ArtifactStore,
    device: str,
    jobs: int = 1,
    threads: int | None = None,
    address: str | None = None,
    names: Iterable[str] = (),
) -> list[dict[Key, float]]:
    """Build every missing stage the cells need: one at a time in this process (jobs 1; threads as given,
    else torch's own), `jobs` at a time in local workers, or on the Dask cluster at `address`; per cell, the
    builds it was first to need and their seconds. With workers, raises one FftoolError naming what failed
    once all that could be built is built (each failure, its reason and log, and what it held back are logged
    first); in this process, the first failure as it came."""
    from fftool.errors import FftoolError
    from fftool.ui import log, warn

    grid = plan(cells)
    nodes = grid.nodes
    inline = jobs == 1 and not address
    per_job = threads if inline else threads_per_job(jobs, threads)
    where = f"the Dask cluster at {address}" if address else f"{jobs} local worker processes"
    firsts = _first_needs(grid, store)
    todo = sum(map(len, firsts))  # every missing build is some cell's first need
    for name, keys, first in zip(names, grid.cells, firsts):
        built, found = [k[0] for k in keys if k in first], [k[0] for k in keys if k not in first]
        log(f"{name}: build {', '.join(built) or 'nothing'}; found {', '.join(found) or 'nothing'}")
    if inline:
        log(f"{todo} of {len(nodes)} stage builds to run in this process")
    else:
        log(f"{todo} of {len(nodes)} stage builds to run on {where}, {per_job} torch thread(s) each")

    def report(event: str, node: Node, detail: str) -> None:
        if event == "failed":
            warn(f"[red]failed[/] {node.label}: {detail} (log: {log_file(store.root, node)})")
        else:
            log(f"{event:>5} {node.label}" + (f" ({detail})" if detail else ""))

    with _executor(jobs, address) as executor:
        outcome = build_all(nodes, store, executor, device, per_job, report)
    for key, needed in outcome.blocked.items():
        warn(f"not built: {nodes[key].label} (it needs {needed}, which failed)")
    if outcome.failed:
        labels = ", ".join(nodes[key].label for key in outcome.failed)
        raise FftoolError(
            f"{len(outcome.failed)} of {todo} stage builds failed ({labels}) and {len(outcome.blocked)} were not "
            f"built because of them; the {len(outcome.built)} others are in the store; run again to retry"
        )
    return [{key: outcome.built[key] for key in first} for first in firsts]


def _first_needs(grid: Plan, store: ArtifactStore) -> list[list[Key]]:
    """Per cell, the missing builds it is the first cell to need (a build shared by later cells is theirs
    to find, as if the cells ran one after another)."""
    claimed: set[Key] = {key for key in grid.nodes if store.lookup(*key) is not None}
    firsts = []
    for keys in grid.cells:
        firsts.append([key for key in keys if key not in claimed])
        claimed.update(keys)
    return firsts
