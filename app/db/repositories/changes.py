"""Changes in what people want: each context's belief as episodes end (``context_beliefs``),
and the changes decided (``change_events``), per person and per fleet, newest first."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy import insert, select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from ..models import ChangeEvent, ContextBelief, User
from ._rows import Prepared, columns, conn, names, table

__all__ = [
    "ChangeRow",
    "add",
    "belief",
    "beliefs",
    "display_names",
    "for_fleet",
    "for_user",
    "put_belief",
]


@dataclass(slots=True)
class ChangeRow:
    id: int | None
    user_pk: int
    fleet: str
    source: str
    time_slot: str
    situation: str
    seq: int
    at: dt.datetime
    utc_offset: int | None
    detected_seq: int
    detected_at: dt.datetime
    before_service: str | None
    before_detail: str | None
    now_service: str | None
    now_detail: str | None
    evidence: list[dict[str, Any]]


_beliefs = table(ContextBelief)
_changes = table(ChangeEvent)
_users = table(User)
_COLS = columns(_changes, ChangeRow)
_NAMES = tuple(n for n in names(ChangeRow) if n != "id")
_INSERT = Prepared(insert(_changes), keyed=True)


def belief(
    session: Session, user_pk: int, time_slot: str, situation: str
) -> tuple[int, dict[str, Any]] | None:
    """(the last episode walked, the walk's document) of the person's context, if any."""
    row = (
        conn(session)
        .execute(
            select(_beliefs.c.upto_seq, _beliefs.c.doc).where(
                _beliefs.c.user_pk == user_pk,
                _beliefs.c.time_slot == time_slot,
                _beliefs.c.situation == situation,
            )
        )
        .first()
    )
    return None if row is None else (int(row[0]), row[1])


def put_belief(
    session: Session,
    user_pk: int,
    time_slot: str,
    situation: str,
    *,
    upto_seq: int,
    doc: dict[str, Any],
) -> None:
    c = conn(session)
    dialect = postgresql if c.dialect.name == "postgresql" else sqlite
    stmt = dialect.insert(_beliefs).values(
        user_pk=user_pk, time_slot=time_slot, situation=situation, upto_seq=upto_seq, doc=doc
    )
    c.execute(
        stmt.on_conflict_do_update(
            index_elements=["user_pk", "time_slot", "situation"],
            set_={"upto_seq": upto_seq, "doc": doc},
        )
    )


def add(session: Session, row: ChangeRow) -> None:
    """Store a change (nothing read back, not even its id: it may be sent in a write's
    batch)."""
    _INSERT.run(session, {n: getattr(row, n) for n in _NAMES})


def for_user(
    session: Session, user_pk: int, *, before_id: int | None, limit: int
) -> list[tuple[ChangeRow, str]]:
    """The person's changes, newest first (before ``before_id``), with their user id."""
    stmt = (
        select(*_COLS, _users.c.user_id)
        .join(_users, _users.c.id == _changes.c.user_pk)
        .where(_changes.c.user_pk == user_pk)
        .order_by(_changes.c.id.desc())
        .limit(limit)
    )
    if before_id is not None:
        stmt = stmt.where(_changes.c.id < before_id)
    return [(ChangeRow(*r[:-1]), r[-1]) for r in conn(session).execute(stmt)]


def for_fleet(
    session: Session,
    fleet: str,
    *,
    since: dt.datetime | None,
    before_id: int | None,
    limit: int,
) -> list[tuple[ChangeRow, str]]:
    """The fleet's changes decided at or after ``since``, newest first (before
    ``before_id``), each with its person's user id."""
    stmt = (
        select(*_COLS, _users.c.user_id)
        .join(_users, _users.c.id == _changes.c.user_pk)
        .where(_changes.c.fleet == fleet)
        .order_by(_changes.c.id.desc())
        .limit(limit)
    )
    if since is not None:
        stmt = stmt.where(_changes.c.detected_at >= since)
    if before_id is not None:
        stmt = stmt.where(_changes.c.id < before_id)
    return [(ChangeRow(*r[:-1]), r[-1]) for r in conn(session).execute(stmt)]


def display_names(session: Session, user_pks: set[int]) -> dict[int, str | None]:
    """The display names of these people, by their number."""
    if not user_pks:
        return {}
    rows = conn(session).execute(
        select(_users.c.id, _users.c.display_name).where(_users.c.id.in_(sorted(user_pks)))
    )
    return {r[0]: r[1] for r in rows}


def beliefs(session: Session, user_pk: int) -> list[tuple[str, str, int, dict[str, Any]]]:
    """(time slot, situation, last episode walked, walk) of each of the person's contexts."""
    rows = conn(session).execute(
        select(_beliefs.c.time_slot, _beliefs.c.situation, _beliefs.c.upto_seq, _beliefs.c.doc)
        .where(_beliefs.c.user_pk == user_pk)
        .order_by(_beliefs.c.time_slot, _beliefs.c.situation)
    )
    return [(r[0], r[1], int(r[2]), r[3]) for r in rows]
