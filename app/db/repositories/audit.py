"""The audit log of admin actions. Entries are added and read, never changed or removed: this
module offers nothing else, and the database refuses both (triggers, see the migrations), with
one exception the database checks too: once a person is erased, the details of the entries about
them are blanked (:func:`redact_erased`)."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy import insert, select, update
from sqlalchemy.orm import Session

from ..models import AuditEntry
from ._rows import columns, conn, table

__all__ = ["ERASED", "AuditRow", "about", "add", "latest", "list_page", "redact_erased"]


@dataclass(slots=True)
class AuditRow:
    id: int | None  # set by the database
    at: dt.datetime
    actor_key_id: str  # "cli": the command line
    actor_role: str
    actor_fleet: str
    action: str  # "user.delete", "model.reset", ...
    target: str  # a user id or a key id
    fleet: str | None  # the target's fleet
    detail: dict[str, Any] | None


ERASED: dict[str, Any] = {"erased": True}  # the detail of an entry about an erased person

_audit = table(AuditEntry)
_COLS = columns(_audit, AuditRow)


def add(session: Session, entry: AuditRow) -> None:
    conn(session).execute(
        insert(_audit).values(
            at=entry.at,
            actor_key_id=entry.actor_key_id,
            actor_role=entry.actor_role,
            actor_fleet=entry.actor_fleet,
            action=entry.action,
            target=entry.target,
            fleet=entry.fleet,
            detail=entry.detail,
        )
    )


def list_page(
    session: Session, *, before_id: int | None, limit: int, fleet: str | None = None
) -> list[AuditRow]:
    """Newest first; of one fleet's users and keys, or of every fleet (``None``)."""
    stmt = select(*_COLS).order_by(_audit.c.id.desc()).limit(limit)
    if before_id is not None:
        stmt = stmt.where(_audit.c.id < before_id)
    if fleet is not None:
        stmt = stmt.where(_audit.c.fleet == fleet)
    return [AuditRow(*row) for row in conn(session).execute(stmt)]


def latest(session: Session, *, fleet: str, action: str) -> AuditRow | None:
    """The newest entry of ``action`` in ``fleet`` (``None``: none yet)."""
    stmt = (
        select(*_COLS)
        .where(_audit.c.fleet == fleet, _audit.c.action == action)
        .order_by(_audit.c.id.desc())
        .limit(1)
    )
    row = conn(session).execute(stmt).first()
    return None if row is None else AuditRow(*row)


def redact_erased(session: Session, *, fleet: str, user_id: str, prefixes: tuple[str, ...]) -> int:
    """Blank the detail of every entry of ``fleet`` about ``user_id`` whose action starts with
    one of ``prefixes`` (``ERASED`` instead): who did what and when stay. Called once the user
    is deleted, in the same transaction; the database refuses it while the user exists. The
    number of entries blanked."""
    about = (_audit.c.fleet == fleet) & (_audit.c.target == user_id)
    family = _audit.c.action.startswith(prefixes[0])
    for prefix in prefixes[1:]:
        family = family | _audit.c.action.startswith(prefix)
    done = conn(session).execute(update(_audit).where(about & family).values(detail=ERASED))
    return int(done.rowcount or 0)


def about(
    session: Session, *, fleet: str, user_id: str, prefixes: tuple[str, ...]
) -> list[AuditRow]:
    """The entries of ``fleet`` about ``user_id`` (actions starting with one of ``prefixes``),
    oldest first."""
    family = _audit.c.action.startswith(prefixes[0])
    for prefix in prefixes[1:]:
        family = family | _audit.c.action.startswith(prefix)
    stmt = (
        select(*_COLS)
        .where(_audit.c.fleet == fleet, _audit.c.target == user_id, family)
        .order_by(_audit.c.id)
    )
    return [AuditRow(*row) for row in conn(session).execute(stmt)]
