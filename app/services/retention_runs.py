"""Retention runs one at a time: whether ``attune retention run`` starts one (from cron, by hand)
or the service does, once a day at ``ATTUNE_RETENTION_AT``, each takes the lease ``retention``
first (:mod:`app.services.leases`), so that several workers, instances and cron never run it
twice at once.

:func:`run_held` is the run of :func:`app.services.retention.run` under the lease, stopped
between two people when the lease is lost or the caller is stopping. :class:`DailyRetention` is
the service's own schedule: a thread, started by the app's lifespan in each worker, that wakes
at the set time, takes the lease unless another process took it for that time already, runs,
and says what happened in the log (logger ``attune.retention``).
"""

from __future__ import annotations

import datetime as dt
import logging
import threading
from collections.abc import Callable

from app.daily import DailyTime
from app.db.session import Database
from app.db.types import utcnow
from app.logs import FIELDS

from . import leases, retention
from .context import ServiceContext
from .leases import Clock, Lease, LeaseHeld, LeaseLost
from .retention import RunReport

__all__ = [
    "LEASE",
    "MAX_SLEEP_S",
    "DailyRetention",
    "RunStopped",
    "run_held",
]

log = logging.getLogger("attune.retention")

LEASE = "retention"
"""The lease every retention run takes."""
MAX_SLEEP_S = 60.0
"""The schedule looks at the clock at least this often (a clock put right, a machine that
slept): it waits for the set time in steps of at most this long."""
STOP_WAIT_S = 5.0
"""How long a stopping worker waits for a run to finish the person it is on."""


class RunStopped(Exception):
    """The run stopped between two people because its caller is stopping (a worker's drain)."""


def run_held(
    db: Database,
    ctx: ServiceContext,
    *,
    since: dt.datetime | None = None,
    fleet: str | None = None,
    batch: int | None = None,
    progress: retention.Progress | None = None,
    stopping: Callable[[], bool] | None = None,
    started: Callable[[Lease], None] | None = None,
    clock: Clock = utcnow,
    ttl: dt.timedelta = leases.TTL,
    renew_every: dt.timedelta = leases.RENEW_EVERY,
) -> RunReport:
    """One retention run (``retention.run``) while holding the lease ``retention``.

    ``since``: only if nobody took the lease at or after that moment (a scheduled run's time:
    the first process to wake runs it, the others find it done). :class:`LeaseHeld` when the
    lease is not free; :class:`LeaseLost` or :class:`RunStopped` after the person in hand when
    the lease was lost or ``stopping()`` says so (a stopped run is safe: the next one goes on
    from there). ``started(lease)`` is called once the lease is held."""
    with leases.held(
        db, LEASE, since=since, ttl=ttl, renew_every=renew_every, clock=clock
    ) as lease:
        if started is not None:
            started(lease)

        def step(in_fleet: str, user_id: str) -> None:
            if progress is not None:
                progress(in_fleet, user_id)
            lease.check()
            if stopping is not None and stopping():
                raise RunStopped

        return retention.run(db, ctx, fleet=fleet, batch=batch, progress=step)


def _when(at: dt.datetime) -> str:
    return f"{at.astimezone(dt.UTC):%Y-%m-%d %H:%M} UTC"


class DailyRetention:
    """The service's retention run, once a day at ``at``, from a thread of its own.

    Each worker of each instance has one; at the set time each tries to take the lease for that
    time, and only the first runs (the others log that it is held, or already ran). A worker
    that was not running at the set time does not catch up: the next run is the next day's
    (run ``attune retention run`` by hand meanwhile, if need be). ``stopping()`` (the worker's
    drain) stops a run between two people, and no new run starts while it holds; :meth:`stop`
    ends the thread.

    ``clock`` and ``wait`` (which sleeps up to so many seconds, and returns True once stopped)
    are the tests' to replace, with ``run`` (what runs at a due time)."""

    def __init__(
        self,
        db: Database,
        ctx: ServiceContext,
        at: DailyTime,
        *,
        stopping: Callable[[], bool] = lambda: False,
        clock: Clock = utcnow,
        wait: Callable[[float], bool] | None = None,
        run: Callable[[dt.datetime], object] | None = None,
    ) -> None:
        self.db, self.ctx, self.at = db, ctx, at
        self.stopping, self.clock = stopping, clock
        self._stop = threading.Event()
        self._wait = wait or self._stop.wait
        self._run = run or self.run_due
        self._thread: threading.Thread | None = None
        self.due: dt.datetime | None = None  # the next run's time, once the thread started

    def start(self) -> None:
        self._thread = threading.Thread(target=self.loop, name="attune-retention", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = STOP_WAIT_S) -> bool:
        """Stop the thread (a run stops after the person in hand): whether it ended within
        ``timeout`` seconds. One that did not is left to the process's exit (it is a daemon;
        its lease runs out by itself)."""
        self._stop.set()
        if self._thread is None:
            return True
        self._thread.join(timeout)
        if self._thread.is_alive():
            log.warning(
                "The retention run is still removing a person's old history; the worker stops "
                "without waiting for it (the next run goes on from there)."
            )
            return False
        return True

    def _stopped(self) -> bool:
        return self._stop.is_set() or self.stopping()

    def loop(self) -> None:
        """Wait for each set time and run then, until stopped."""
        self.due = self.at.next_after(self.clock())
        log.info("Retention runs every day at %s; the next run is at %s.", self.at, _when(self.due))
        while not self._stop.is_set():
            now = self.clock()
            if now < self.due:
                self._wait(min((self.due - now).total_seconds(), MAX_SLEEP_S))
                continue
            if self._stopped():
                break
            self._run(self.due)
            self.due = self.at.next_after(max(self.clock(), self.due))

    def run_due(self, due: dt.datetime) -> RunReport | None:
        """The run of the set time ``due``, if no other process took it: its report, or None
        when it was skipped, stopped or failed (each said in the log)."""
        what = f"Retention run of {_when(due)}"
        fields = {"due": due.isoformat()}

        def started(lease: Lease) -> None:
            log.info(
                "%s started (lease held by %s until %s, renewed while it runs).",
                what,
                lease.holder,
                f"{lease.expires_at.astimezone(dt.UTC):%H:%M:%S} UTC",
                extra={FIELDS: {**fields, "holder": lease.holder}},
            )

        try:
            report = run_held(
                self.db,
                self.ctx,
                since=due,
                stopping=self._stopped,
                started=started,
                clock=self.clock,
            )
        except LeaseHeld as held:
            log.info("%s skipped: %s.", what, held.sentence(), extra={FIELDS: fields})
            return None
        except RunStopped:
            log.info(
                "%s stopped: the worker is shutting down; the next run goes on from there.",
                what,
                extra={FIELDS: fields},
            )
            return None
        except LeaseLost as lost:
            log.warning("%s stopped: %s.", what, lost, extra={FIELDS: fields})
            return None
        except Exception:
            log.exception(
                "%s failed; the next run goes on from where it stopped.",
                what,
                extra={FIELDS: fields},
            )
            return None
        seconds = (report.finished_at or report.started_at) - report.started_at
        log.info(
            "%s finished in %.1f s: %d fleet%s, %d episodes and %d journal entries removed.",
            what,
            seconds.total_seconds(),
            len(report.fleets),
            "" if len(report.fleets) == 1 else "s",
            report.episodes_removed,
            report.journal_removed,
            extra={
                FIELDS: {
                    **fields,
                    "fleets": len(report.fleets),
                    "episodes_removed": report.episodes_removed,
                    "journal_removed": report.journal_removed,
                }
            },
        )
        return report
