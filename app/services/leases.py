"""Leases: a job that one process of the deployment runs at a time, whichever worker, instance or
command starts it (the retention run).

:func:`held` takes the lease in a transaction of its own (or raises :class:`LeaseHeld`), renews
it from a thread of its own every ``renew_every`` while the block runs, and lets it go at the
end. A holder that dies (``kill -9``, a lost machine) renews no more: its lease runs out after
``ttl`` and the next taker goes ahead. If a renewal finds that someone else took the lease
meanwhile (it ran out while this holder could not reach the database), the lease is *lost*:
:meth:`Lease.check` raises :class:`LeaseLost`, and the holder's work should stop there.

Times are the processes' own clocks (UTC): the instances of a deployment must agree on the time
to well within ``ttl`` (NTP does). Nothing is kept on a database connection between
transactions, so the leases work through a pooler in transaction pooling.
"""

from __future__ import annotations

import datetime as dt
import logging
import os
import secrets
import socket
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

from app.db.repositories import leases as repo
from app.db.repositories.leases import LeaseRow
from app.db.session import Database
from app.db.types import utcnow

__all__ = [
    "RENEW_EVERY",
    "TTL",
    "Clock",
    "Lease",
    "LeaseHeld",
    "LeaseLost",
    "held",
    "holder_name",
    "take",
]

log = logging.getLogger("attune.leases")

TTL = dt.timedelta(minutes=5)
"""How long a lease lasts unless renewed: how long a dead holder keeps the job from others."""
RENEW_EVERY = dt.timedelta(minutes=1)
"""How often a holder renews its lease while it works."""

Clock = Callable[[], dt.datetime]


class LeaseHeld(Exception):
    """The lease was not free at ``now``: someone holds it (``current``), or it is free but
    was taken at or after the moment given (``since``: :attr:`already_ran`)."""

    def __init__(
        self, name: str, current: LeaseRow | None, *, now: dt.datetime, since: dt.datetime | None
    ) -> None:
        self.name, self.current, self.since = name, current, since
        self.already_ran = (
            current is not None
            and current.expires_at <= now
            and since is not None
            and current.acquired_at >= since
        )
        super().__init__(self.sentence())

    def sentence(self) -> str:
        """Why, in words: ``another process holds the lease: web-1:4242:9f2c1a, since ...``."""
        c = self.current
        if c is None:  # taken and let go between the two statements: as good as held
            return "another process held the lease a moment ago"
        if self.already_ran:
            return f"it already ran: {c.holder} took the lease at {_when(c.acquired_at)}"
        return f"another process holds the lease: {self.holding()}"

    def holding(self) -> str:
        """Who holds it and how long: ``web-1:4242:9f2c1a, since ..., until ... unless it
        renews it``."""
        c = self.current
        if c is None:
            return "a moment ago"
        return (
            f"{c.holder}, since {_when(c.acquired_at)}, until {_when(c.expires_at)} unless it "
            "renews it"
        )


class LeaseLost(Exception):
    """The lease ran out while its holder could not renew it, and someone else took it."""


def _when(at: dt.datetime) -> str:
    return f"{at.astimezone(dt.UTC):%Y-%m-%d %H:%M:%S} UTC"


def holder_name() -> str:
    """This process's name for one taking: ``host:pid:random`` (unique, and says where)."""
    return f"{socket.gethostname()}:{os.getpid()}:{secrets.token_hex(3)}"


@dataclass
class Lease:
    """One taking of the lease ``name`` by ``holder``, until ``expires_at`` unless renewed."""

    db: Database
    name: str
    holder: str
    acquired_at: dt.datetime
    expires_at: dt.datetime
    ttl: dt.timedelta
    lost: threading.Event = field(default_factory=threading.Event)

    def renew(self, now: dt.datetime) -> bool:
        """Hold it ``ttl`` from ``now``; False (and lost) when someone else took it."""
        until = now + self.ttl
        with self.db.transaction() as session:
            kept = repo.renew(session, self.name, holder=self.holder, until=until)
        if kept:
            self.expires_at = until
        else:
            self.lost.set()
        return kept

    def release(self, now: dt.datetime) -> None:
        """Let it go: the next taker need not wait for it to run out."""
        with self.db.transaction() as session:
            repo.release(session, self.name, holder=self.holder, now=now)

    def check(self) -> None:
        """Raise :class:`LeaseLost` once a renewal found the lease taken by someone else."""
        if self.lost.is_set():
            raise LeaseLost(
                f"the lease {self.name!r} ran out while {self.holder} could not renew it, and "
                "another process took it"
            )


def take(
    db: Database,
    name: str,
    *,
    now: dt.datetime,
    ttl: dt.timedelta = TTL,
    since: dt.datetime | None = None,
    holder: str | None = None,
) -> Lease:
    """Take the lease ``name`` at ``now`` for ``ttl`` (with ``since``: unless someone took it at
    or after that moment), in a transaction of its own; :class:`LeaseHeld` when it is not free."""
    holder = holder or holder_name()
    with db.transaction() as session:
        taken = repo.take(
            session, name, holder=holder, now=now, until=now + ttl, unless_taken_since=since
        )
        current = None if taken else repo.get(session, name)
    if not taken:
        raise LeaseHeld(name, current, now=now, since=since)
    return Lease(db, name, holder, now, now + ttl, ttl)


@contextmanager
def held(
    db: Database,
    name: str,
    *,
    since: dt.datetime | None = None,
    ttl: dt.timedelta = TTL,
    renew_every: dt.timedelta = RENEW_EVERY,
    clock: Clock = utcnow,
    holder: str | None = None,
) -> Iterator[Lease]:
    """The lease ``name`` for the block (see the module): taken at ``clock()``, renewed every
    ``renew_every`` by a thread of its own, let go at the end. With ``holder``: the lease that
    another process took for this one under that name (a worker that starts a process to do
    the job), renewed at once (:class:`LeaseHeld` when it is no longer that holder's)."""
    if holder is None:
        lease = take(db, name, now=clock(), ttl=ttl, since=since)
    else:
        now = clock()
        lease = Lease(db, name, holder, now, now, ttl)
        if not lease.renew(now):
            with db.transaction(write=False) as session:
                current = repo.get(session, name)
            raise LeaseHeld(name, current, now=now, since=None)
    stop = threading.Event()

    def keep() -> None:
        while not stop.wait(renew_every.total_seconds()):
            try:
                if not lease.renew(clock()):
                    log.warning("%s lost the lease %r: another process took it", lease.holder, name)
                    return
            except Exception as exc:  # the database is away: try again, until it runs out
                log.warning("%s could not renew the lease %r: %s", lease.holder, name, exc)

    renewer = threading.Thread(target=keep, name=f"attune-lease-{name}", daemon=True)
    renewer.start()
    try:
        yield lease
    finally:
        stop.set()
        renewer.join()
        if not lease.lost.is_set():
            try:
                lease.release(clock())
            except Exception as exc:  # it runs out by itself
                log.warning("%s could not let the lease %r go: %s", lease.holder, name, exc)
