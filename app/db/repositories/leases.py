"""Leases (``leases``): a job's row, taken by a conditional ``UPDATE`` or the first ``INSERT``,
renewed and let go by its holder. Each call is meant to be its transaction's only work, so that
the row is locked (PostgreSQL) or the write lock held (SQLite) for one statement or two."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass

from sqlalchemy import select, update
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from ..models import Lease
from ._rows import columns, conn, record, table

__all__ = ["LeaseRow", "get", "release", "renew", "take"]


@dataclass(slots=True)
class LeaseRow:
    name: str
    holder: str
    acquired_at: dt.datetime
    expires_at: dt.datetime


_leases = table(Lease)


def get(session: Session, name: str) -> LeaseRow | None:
    return record(
        LeaseRow,
        conn(session)
        .execute(select(*columns(_leases, LeaseRow)).where(_leases.c.name == name))
        .first(),
    )


def take(
    session: Session,
    name: str,
    *,
    holder: str,
    now: dt.datetime,
    until: dt.datetime,
    unless_taken_since: dt.datetime | None = None,
) -> bool:
    """Take the lease for ``holder`` until ``until`` if it is free at ``now`` (and, with
    ``unless_taken_since``, nobody took it at or after that moment): whether it was taken.

    Two takers at once: on PostgreSQL the second ``UPDATE`` waits for the first's row lock,
    then finds the row no longer free (``READ COMMITTED`` checks the condition again on the
    row as committed), and the second ``INSERT`` of a new row does nothing; on SQLite the
    write transactions take turns."""
    c = conn(session)
    free = (_leases.c.name == name) & (_leases.c.expires_at <= now)
    if unless_taken_since is not None:
        free &= _leases.c.acquired_at < unless_taken_since
    values = {"holder": holder, "acquired_at": now, "expires_at": until}
    if c.execute(update(_leases).where(free).values(**values)).rowcount:
        return True
    dialect = postgresql if c.dialect.name == "postgresql" else sqlite
    first = (
        dialect.insert(_leases)
        .values(name=name, **values)
        .on_conflict_do_nothing(index_elements=["name"])
    )
    # RETURNING, not rowcount: psycopg gives no count for an INSERT ... ON CONFLICT here.
    return c.execute(first.returning(_leases.c.name)).first() is not None


def renew(session: Session, name: str, *, holder: str, until: dt.datetime) -> bool:
    """Move the end of ``holder``'s lease to ``until``: whether ``holder`` still held it (no
    one took it after it ran out)."""
    done = conn(session).execute(
        update(_leases)
        .where(_leases.c.name == name, _leases.c.holder == holder)
        .values(expires_at=until)
    )
    return bool(done.rowcount)


def release(session: Session, name: str, *, holder: str, now: dt.datetime) -> bool:
    """Let ``holder``'s lease go (it ends ``now``): whether ``holder`` still held it."""
    done = conn(session).execute(
        update(_leases)
        .where(_leases.c.name == name, _leases.c.holder == holder, _leases.c.expires_at > now)
        .values(expires_at=now)
    )
    return bool(done.rowcount)
