"""Run many seeded experiment runs in parallel, with a progress bar, in a deterministic order.

One job is one method on one protocol with one seed (all ``n_users`` users): coarse enough that
pickling and process start-up stay small next to the simulation itself.
"""

from __future__ import annotations

import functools
import json
import multiprocessing
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from typing import TypeVar

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskProgressColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from app.learning import Mission, office_mission
from app.learning.evaluation import Method, Protocol, RunResult, run

__all__ = [
    "Job",
    "JobError",
    "default_workers",
    "jobs_for",
    "run_job",
    "run_jobs",
    "run_tasks",
]

T = TypeVar("T")
R = TypeVar("R")


@dataclass(frozen=True)
class Job:
    """One run to do: a method on a protocol with a seed, for ``n_users`` simulated users."""

    method: Method
    protocol: Protocol
    seed: int
    n_users: int = 6
    user_params: tuple[tuple[str, float], ...] = ()  # overrides of the simulated users
    mission: str | None = None  # the mission as canonical JSON; None: the office mission

    def describe(self) -> str:
        """A short human-readable name for messages."""
        return f"{self.method.label} / {self.protocol.name} / seed {self.seed}"


class JobError(RuntimeError):
    """A job raised; the message names the job, the cause is chained."""


def jobs_for(
    methods: Iterable[Method],
    protocols: Iterable[Protocol],
    seeds: int,
    n_users: int = 6,
    user_params: Mapping[str, float] | None = None,
    mission: Mission | None = None,
) -> list[Job]:
    """Every method x protocol x seed (seeds 0..seeds-1), ordered protocol, method, seed;
    the simulated users live in ``mission`` (default: the paper's office mission)."""
    methods, protocols = list(methods), list(protocols)
    overrides = tuple(sorted((user_params or {}).items()))
    document = None if mission is None else json.dumps(mission.to_dict(), sort_keys=True)
    return [
        Job(method, protocol, seed, n_users, overrides, document)
        for protocol in protocols
        for method in methods
        for seed in range(seeds)
    ]


@functools.lru_cache(maxsize=4)
def _mission(document: str | None) -> Mission:
    if document is None:
        return office_mission()
    return Mission.from_dict(json.loads(document), source="--mission")


def run_job(job: Job) -> RunResult:
    """Do one job; the mission is built here, in the worker (once), from its JSON."""
    return run(
        job.method,
        job.protocol,
        job.seed,
        _mission(job.mission),
        n_users=job.n_users,
        user_params=dict(job.user_params),
    )


def default_workers() -> int:
    """The default number of worker processes: one per CPU."""
    return os.cpu_count() or 1


def _progress(console: Console | None, enabled: bool) -> Progress:
    """A progress bar with description, bar, done/total, percentage, elapsed time and ETA."""
    return Progress(
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TaskProgressColumn(),
        TextColumn("elapsed"),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
        console=console,
        disable=not enabled,
    )


def run_jobs(
    jobs: Sequence[Job],
    workers: int | None = None,
    *,
    description: str = "Running",
    console: Console | None = None,
    progress: bool = True,
) -> list[RunResult]:
    """Run ``jobs`` on ``workers`` processes (default: one per CPU); results in job order.

    ``workers == 1`` runs in this process, without a pool. Longer protocols are submitted first
    so that the last jobs to finish are short ones. Workers are started with "spawn", which is
    safe next to the progress bar's refresh thread and warns about nothing.
    """
    return run_tasks(
        run_job,
        jobs,
        workers,
        description=description,
        console=console,
        progress=progress,
        size=lambda job: job.protocol.n_events,
        describe=Job.describe,
    )


def run_tasks(
    function: Callable[[T], R],
    tasks: Sequence[T],
    workers: int | None = None,
    *,
    description: str = "Running",
    console: Console | None = None,
    progress: bool = True,
    size: Callable[[T], float] | None = None,
    describe: Callable[[T], str] = str,
) -> list[R]:
    """``function(task)`` for every task on ``workers`` processes (default: one per CPU), with a
    progress bar; results in task order. ``function`` must be a module-level function (workers
    are spawned and import it) and tasks and results must pickle.

    ``workers == 1`` runs in this process, without a pool. Tasks of the largest ``size`` are
    submitted first, so that the last to finish are short ones. A task that raises stops the
    whole run with a :class:`JobError` naming it (``describe``).
    """
    workers = default_workers() if workers is None else workers
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}.")
    results: list[R | None] = [None] * len(tasks)
    with _progress(console, progress) as bar:
        task_id = bar.add_task(description, total=len(tasks))
        if workers == 1 or len(tasks) <= 1:
            for i, task in enumerate(tasks):
                try:
                    results[i] = function(task)
                except Exception as exc:
                    raise _failed(describe(task), exc) from exc
                bar.advance(task_id)
        else:
            order = list(range(len(tasks)))
            if size is not None:
                order.sort(key=lambda i: -size(tasks[i]))
            context = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(min(workers, len(tasks)), mp_context=context) as pool:
                futures: dict[Future[R], int] = {}
                try:
                    for i in order:
                        futures[pool.submit(function, tasks[i])] = i
                    for future in as_completed(futures):
                        i = futures[future]
                        try:
                            results[i] = future.result()
                        except Exception as exc:
                            raise _failed(describe(tasks[i]), exc) from exc
                        bar.advance(task_id)
                except BaseException:
                    for future in futures:
                        future.cancel()
                    raise
    return [result for result in results if result is not None]


def _failed(what: str, exc: Exception) -> JobError:
    """The error to raise when the run described by ``what`` raised ``exc``."""
    return JobError(f"Run {what} failed: {exc!r}")
