"""Prometheus metrics: the requests, the worker processes, the database and how well each fleet's
learners do.

With several workers (``attune serve --workers N``, or a metrics port of its own) every process
writes to ``PROMETHEUS_MULTIPROC_DIR`` and ``/metrics`` sums them (prometheus_client's
multiprocess mode); a gauge says how its workers' values combine (``livesum``, ``livemax``: the
supervisor forgets the values of a worker that died).

The robots' requests pay only counter increments: what describes a process (CPU, memory, the
connection pool, the learner cache, the event loop, the drain) is sampled once a second by a task
of each worker (:meth:`Metrics.watch`) and before each scrape, from counts the parts keep anyway.
No metric has a label per person: fleets, routes, action kinds and responses only.
"""

from __future__ import annotations

import asyncio
import os
import resource
import sys
import threading
import time
from collections import deque
from contextvars import ContextVar, Token
from typing import TYPE_CHECKING, Any

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest
from prometheus_client.multiprocess import MultiProcessCollector
from sqlalchemy import event
from sqlalchemy.engine import Engine
from sqlalchemy.pool import Pool

from app.db.pool import MeteredQueuePool

if TYPE_CHECKING:
    from app.db.session import Database
    from app.services.context import LearnerCache

    from .lifecycle import Drain

__all__ = ["Metrics", "begin_round_trips", "end_round_trips"]

TICK_S = 0.5
"""How often each worker's task wakes: its lateness is the event loop's lag."""

LAG_WINDOW = 20
"""Wake-ups the worst lag is taken over (10 s)."""

STALL_WINDOW_S = 5
"""Seconds the worst event-loop stall is taken over (``attune_event_loop_stall_max_seconds``)."""

# The round trips of the request being served: [count, in a pipeline since the last one].
_TRIPS: ContextVar[list[int] | None] = ContextVar("attune_round_trips", default=None)


def begin_round_trips() -> tuple[list[int], Token[list[int] | None]]:
    """A count of round trips for the request about to run in this context (``[0]`` is the
    count), and the token that :func:`end_round_trips` takes when it is done."""
    cell = [0, 0]
    return cell, _TRIPS.set(cell)


def end_round_trips(token: Token[list[int] | None]) -> None:
    _TRIPS.reset(token)


class Metrics:
    """One app's metrics (tests make many apps in one process: each has its own registry)."""

    def __init__(self) -> None:
        _install_round_trip_counting()
        r = self.registry = CollectorRegistry()
        self.requests = Counter(
            "attune_http_requests",
            "HTTP requests by route and status.",
            ["method", "route", "status"],
            registry=r,
        )
        self.latency = Histogram(
            "attune_http_request_duration_seconds",
            "HTTP request latency by route.",
            ["method", "route"],
            registry=r,
            buckets=(0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0),
        )
        self.round_trips = Counter(
            "attune_db_round_trips",
            "Round trips to PostgreSQL by the route of the request that made them (statements "
            "sent alone, pipelines, BEGIN and COMMIT).",
            ["route"],
            registry=r,
        )
        self.decisions = Counter(
            "attune_decisions",
            "Decisions sent to robots by fleet and action kind.",
            ["fleet", "kind"],
            registry=r,
        )
        self.outcomes = Counter(
            "attune_outcomes",
            "Outcomes reported by fleet, action kind and response.",
            ["fleet", "kind", "response"],
            registry=r,
        )
        self.episodes_ended = Counter(
            "attune_episodes_ended",
            "Episodes ended by an outcome, by fleet.",
            ["fleet"],
            registry=r,
        )
        self.reward_positive = Counter(
            "attune_episode_reward_positive",
            "Sum of the total rewards of the episodes that ended with a positive one, by fleet.",
            ["fleet"],
            registry=r,
        )
        self.reward_negative = Counter(
            "attune_episode_reward_negative",
            "Sum of the magnitudes of the total rewards of the episodes that ended with a "
            "negative one, by fleet.",
            ["fleet"],
            registry=r,
        )
        self.cpu = Counter(
            "attune_process_cpu_seconds",
            "CPU time (user and system) of the worker processes.",
            registry=r,
        )
        self.memory = Gauge(
            "attune_process_resident_memory_bytes",
            "Resident memory of the live worker processes.",
            registry=r,
            multiprocess_mode="livesum",
        )
        self.workers = Gauge(
            "attune_workers", "Live worker processes.", registry=r, multiprocess_mode="livesum"
        )
        self.pool_in_use = Gauge(
            "attune_db_pool_connections_in_use",
            "Connections of the workers' database pools in use.",
            registry=r,
            multiprocess_mode="livesum",
        )
        self.pool_max = Gauge(
            "attune_db_pool_connections_max",
            "Connections the workers' database pools may open.",
            registry=r,
            multiprocess_mode="livesum",
        )
        self.pool_waits = Counter(
            "attune_db_pool_waits",
            "Requests for a connection made while the pool had every connection in use.",
            registry=r,
        )
        self.pool_wait_seconds = Counter(
            "attune_db_pool_wait_seconds",
            "Time those requests waited for a connection.",
            registry=r,
        )
        self.cache_hits = Counter(
            "attune_learner_cache_hits",
            "Learners found decoded in a worker's cache at the version the request needed.",
            registry=r,
        )
        self.cache_misses = Counter(
            "attune_learner_cache_misses",
            "Learners a request had to load (not cached, or cached at another version).",
            registry=r,
        )
        self.loop_lag = Histogram(
            "attune_event_loop_lag_seconds",
            "How late each worker's event loop woke a task that slept half a second.",
            registry=r,
            buckets=(0.001, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0),
        )
        self.loop_lag_max = Gauge(
            "attune_event_loop_lag_max_seconds",
            "The worst lateness of a worker's event loop over the last 10 seconds.",
            registry=r,
            multiprocess_mode="livemax",
        )
        self.loop_stall = Histogram(
            "attune_event_loop_stall_seconds",
            "How late each worker's loop watchdog woke (every ATTUNE_LOOP_WATCH_MS): how long "
            "the event loop was held up by the work it ran.",
            registry=r,
            buckets=(0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5),
        )
        self.loop_stall_max = Gauge(
            "attune_event_loop_stall_max_seconds",
            "The worst stall of each worker's event loop over the last 5 seconds (a series per "
            "worker process).",
            registry=r,
            multiprocess_mode="liveall",
        )
        self.loop_busy_max = Gauge(
            "attune_event_loop_busy_stall_max_seconds",
            "The worst stall of each worker's event loop over the last 5 seconds, counting only "
            "the time its thread ran (its CPU time in the stall, at most): the loop held up by "
            "its own computing; the rest of a stall is a wait, for a CPU of a busy machine, for "
            "the interpreter's lock, or in a blocking call on the loop (a series per worker "
            "process).",
            registry=r,
            multiprocess_mode="liveall",
        )
        self.writes = Counter(
            "attune_robot_writes",
            "PostgreSQL: the robots' writes (starts and outcomes) by where they ran: inline on "
            "the event loop, or in the thread pool.",
            ["path"],
            registry=r,
        )
        self.db_round_trip = Gauge(
            "attune_db_round_trip_seconds",
            "PostgreSQL, ATTUNE_PG_INLINE_WRITES=auto: the round trip to the database each "
            "worker measured (the median of its last probes; the largest worker's).",
            registry=r,
            multiprocess_mode="livemax",
        )
        self.draining = Gauge(
            "attune_draining",
            "1 while a worker is shutting down (after SIGTERM or SIGINT), else 0.",
            registry=r,
            multiprocess_mode="livemax",
        )
        self._by_request: dict[tuple[str, str, int], Any] = {}
        self._by_route: dict[tuple[str, str], Any] = {}
        self._trips_by_route: dict[str, Any] = {}
        self._by_decision: dict[tuple[str, str], Any] = {}
        self._by_outcome: dict[tuple[str, str, str], Any] = {}
        self._by_fleet: dict[str, tuple[Any, Any, Any]] = {}
        self._lags: deque[float] = deque(maxlen=LAG_WINDOW)
        self._inline_writes, self._pool_writes = (
            self.writes.labels("inline"),
            self.writes.labels("pool"),
        )
        self._lock = threading.Lock()
        self._seen: dict[str, tuple[object, float]] = {}
        self._db: Database | None = None
        self._cache: LearnerCache | None = None
        self._drain: Drain | None = None

    # -- the request path: counter increments only (each series' child kept: no label lookup) -
    def observe_request(
        self, method: str, route: str, status: int, seconds: float, round_trips: int = 0
    ) -> None:
        key = (method, route, status)
        counter = self._by_request.get(key)
        if counter is None:
            counter = self._by_request[key] = self.requests.labels(method, route, str(status))
        counter.inc()
        timer = self._by_route.get((method, route))
        if timer is None:
            timer = self._by_route[(method, route)] = self.latency.labels(method, route)
        timer.observe(seconds)
        if round_trips:
            trips = self._trips_by_route.get(route)
            if trips is None:
                trips = self._trips_by_route[route] = self.round_trips.labels(route)
            trips.inc(round_trips)

    def decision_sent(self, fleet: str, kind: str) -> None:
        counter = self._by_decision.get((fleet, kind))
        if counter is None:
            counter = self._by_decision[(fleet, kind)] = self.decisions.labels(fleet, kind)
        counter.inc()

    def outcome_reported(
        self, fleet: str, kind: str, response: str, episode: dict[str, Any] | None
    ) -> None:
        """An outcome was stored (not a replay); ``episode`` is the answer's brief of its
        episode: when the outcome ended it, its total reward counts towards the fleet's."""
        key = (fleet, kind, response)
        counter = self._by_outcome.get(key)
        if counter is None:
            counter = self._by_outcome[key] = self.outcomes.labels(fleet, kind, response)
        counter.inc()
        if episode is None or episode.get("status") != "closed":
            return
        ended = self._by_fleet.get(fleet)
        if ended is None:
            ended = self._by_fleet[fleet] = (
                self.episodes_ended.labels(fleet),
                self.reward_positive.labels(fleet),
                self.reward_negative.labels(fleet),
            )
        ended[0].inc()
        reward = float(episode.get("total_reward") or 0.0)
        if reward > 0:
            ended[1].inc(reward)
        elif reward < 0:
            ended[2].inc(-reward)

    # -- the worker's own figures, sampled --------------------------------------------------------
    def attach(self, *, db: Database, cache: LearnerCache, drain: Drain) -> None:
        """The parts whose counts :meth:`sample` reads."""
        self._db, self._cache, self._drain = db, cache, drain

    def sample(self) -> None:
        """Bring this process's figures up to date (the task of :meth:`watch` does it every
        second; ``/metrics`` before it answers)."""
        with self._lock:
            times = os.times()
            self._add(self.cpu, "cpu", None, times.user + times.system)
            self.memory.set(_resident_bytes())
            self.workers.set(1)
            if self._db is not None:
                pool = self._db.engine.pool
                if isinstance(pool, MeteredQueuePool):
                    self.pool_in_use.set(pool.checkedout())
                    self.pool_max.set(pool.capacity or 0)
                    self._add(self.pool_waits, "waits", pool, pool.waits)
                    self._add(self.pool_wait_seconds, "wait_seconds", pool, pool.wait_seconds)
                db = self._db
                self._add(self._inline_writes, "inline", db, db.inlined)
                self._add(self._pool_writes, "pool", db, db.deferred + db.pooled)
                if db.round_trip_s is not None:
                    self.db_round_trip.set(db.round_trip_s)
            if self._cache is not None:
                self._add(self.cache_hits, "hits", self._cache, self._cache.hits)
                self._add(self.cache_misses, "misses", self._cache, self._cache.misses)
            self.draining.set(1 if self._drain is not None and self._drain.draining else 0)
            self.loop_lag_max.set(max(self._lags, default=0.0))

    def _add(self, counter: Counter, name: str, source: object, total: float) -> None:
        """Increment ``counter`` by what ``total`` (a running count of ``source``) grew since
        the last sample; a new source (a pool made anew) starts from zero."""
        seen = self._seen.get(name)
        before = seen[1] if seen is not None and seen[0] is source else 0.0
        if total > before:
            counter.inc(total - before)
        self._seen[name] = (source, total)

    async def watch(self, tick: float = TICK_S) -> None:
        """Each worker's task, for its life: measure how late the event loop wakes it, and
        sample the figures every other wake-up."""
        loop = asyncio.get_running_loop()
        n = 0
        while True:
            start = loop.time()
            await asyncio.sleep(tick)
            lag = max(0.0, loop.time() - start - tick)
            self.loop_lag.observe(lag)
            self._lags.append(lag)
            n += 1
            if n % 2 == 0:
                self.sample()

    async def watch_stalls(self, tick_ms: float) -> None:
        """Each worker's loop watchdog, for its life: wake every ``tick_ms`` and count how late
        the loop woke it as a stall (a stall shorter than the tick may be seen in part: it is
        seen whole only when it begins before the watchdog's wake-up is due)."""
        loop = asyncio.get_running_loop()
        tick = tick_ms / 1000.0
        # The worst (wall, busy) of each past second; busy: the part of a stall the loop's
        # thread ran, at most its CPU time over the tick and the stall (the rest it waited:
        # for a CPU of a busy machine, for the interpreter's lock, or in a blocking call).
        seconds: deque[tuple[float, float]] = deque(maxlen=STALL_WINDOW_S)
        worst = busiest = shown = shown_busy = 0.0
        second_ends = loop.time() + 1.0
        observe, show, show_busy = (
            self.loop_stall.observe,
            self.loop_stall_max.set,
            self.loop_busy_max.set,
        )
        cpu = time.thread_time
        while True:
            start, ran = loop.time(), cpu()
            await asyncio.sleep(tick)
            now = loop.time()
            stall = max(0.0, now - start - tick)
            busy = min(stall, cpu() - ran)
            observe(stall)
            worst, busiest = max(worst, stall), max(busiest, busy)
            if now >= second_ends:
                seconds.append((worst, busiest))
                worst = busiest = 0.0
                second_ends = now + 1.0
                shown = max(w for w, _ in seconds)
                shown_busy = max(b for _, b in seconds)
                show(shown)
                show_busy(shown_busy)
                continue
            if worst > shown:
                shown = worst
                show(shown)
            if busiest > shown_busy:
                shown_busy = busiest
                show_busy(shown_busy)

    def render(self) -> bytes:
        if os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
            registry = CollectorRegistry()
            MultiProcessCollector(registry)  # type: ignore[no-untyped-call]
            return generate_latest(registry)
        return generate_latest(self.registry)


def _resident_bytes() -> float:
    """This process's resident memory: Linux's current figure, elsewhere the peak."""
    try:
        with open("/proc/self/statm", "rb") as statm:
            return float(int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE"))
    except (OSError, ValueError, IndexError):
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return float(peak if sys.platform == "darwin" else peak * 1024)


# -- round trips to PostgreSQL, counted on psycopg's cursors ---------------------------------------
_installed = False
_install_lock = threading.Lock()
_counting_cursors: dict[type, type] = {}


def _install_round_trip_counting() -> None:
    """Count, per request, the round trips its statements make to PostgreSQL, once per process.

    Every statement goes through a cursor of psycopg (SQLAlchemy's, and the repositories'
    prepared statements on the driver's connection), so each new psycopg connection gets a
    cursor class that counts; COMMIT and ROLLBACK are counted by SQLAlchemy's events. Outside a
    request nothing is counted.
    """
    global _installed
    with _install_lock:
        if _installed:
            return
        event.listen(Pool, "connect", _on_connect)
        event.listen(Engine, "commit", _on_transaction_end)
        event.listen(Engine, "rollback", _on_transaction_end)
        _installed = True


def _on_connect(dbapi_connection: Any, _record: Any) -> None:
    base = getattr(dbapi_connection, "cursor_factory", None)
    if base is None or not hasattr(dbapi_connection, "pgconn"):
        return  # not psycopg: SQLite has no round trips
    counting = _counting_cursors.get(base)
    if counting is None:
        counting = _counting_cursors[base] = _counting_cursor(base)
    dbapi_connection.cursor_factory = counting


def _count(cursor: Any) -> None:
    cell = _TRIPS.get()
    if cell is None:
        return
    conn = cursor.connection
    pgconn = conn.pgconn
    if pgconn.pipeline_status:  # a pipeline's statements travel together: one round trip
        if not cell[1]:
            cell[0] += 1
            cell[1] = 1
        return
    cell[1] = 0
    if not pgconn.transaction_status and not conn.autocommit:
        cell[0] += 1  # psycopg sends BEGIN before the transaction's first statement
    cell[0] += 1


def _counting_cursor(base: Any) -> type:
    """``base`` (psycopg's ``Cursor``, or the class the connection was given) counting."""
    run, run_many = base.execute, base.executemany

    def execute(self: Any, *args: Any, **kwargs: Any) -> Any:
        _count(self)
        return run(self, *args, **kwargs)

    def executemany(self: Any, *args: Any, **kwargs: Any) -> Any:
        _count(self)  # psycopg sends the rows in one pipeline
        return run_many(self, *args, **kwargs)

    return type(base.__name__, (base,), {"execute": execute, "executemany": executemany})


def _on_transaction_end(conn: Any) -> None:
    cell = _TRIPS.get()
    if cell is None:
        return
    try:
        pgconn = getattr(conn.connection.driver_connection, "pgconn", None)
    except Exception:  # an invalidated connection: nothing goes to the server
        return
    if pgconn is not None and pgconn.transaction_status:  # psycopg skips it when idle
        cell[0] += 1
        cell[1] = 0
