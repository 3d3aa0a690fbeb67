"""The audit log of admin actions. Entries are added and read, never changed or removed: this
module offers nothing else, and the database refuses both (triggers, see the migrations)."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy import insert, select
from sqlalchemy.orm import Session

from ..models import AuditEntry
from ._rows import columns, conn, table

__all__ = ["AuditRow", "add", "list_page"]


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
