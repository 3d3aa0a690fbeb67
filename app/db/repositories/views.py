"""Who looked at a person's data: added as staff and admins read it, listed newest first,
removed with the person (the foreign key cascades) or once older than the window."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass

from sqlalchemy import delete, insert, literal, select
from sqlalchemy.orm import Session

from ..models import ApiKey, DataView, User
from ._rows import conn, table

__all__ = ["ViewRow", "add", "list_page", "prune"]


@dataclass(slots=True)
class ViewRow:
    id: int
    at: dt.datetime
    user_id: str
    fleet: str
    actor_key_id: str
    actor_role: str
    actor_fleet: str
    actor_name: str | None  # the key's name, if it has one and still exists
    what: str
    via: str


_views = table(DataView)
_users = table(User)
_keys = table(ApiKey)
_LISTED = [
    _views.c.id,
    _views.c.at,
    _users.c.user_id,
    _views.c.fleet,
    _views.c.actor_key_id,
    _views.c.actor_role,
    _views.c.actor_fleet,
    _keys.c.name,
    _views.c.what,
    _views.c.via,
]


def add(
    session: Session,
    *,
    fleet: str,
    user_id: str,
    at: dt.datetime,
    actor: tuple[str, str, str],
    what: str,
    via: str,
) -> int:
    """Record a read of ``user_id`` of ``fleet`` by ``actor`` (key id, role, fleet), in one
    statement (nothing when the person no longer exists): the rows added, 0 or 1."""
    key_id, role, actor_fleet = actor
    chosen = select(
        _users.c.id,
        literal(fleet),
        literal(at, DataView.__table__.c.at.type),
        literal(key_id),
        literal(role),
        literal(actor_fleet),
        literal(what),
        literal(via),
    ).where(_users.c.fleet == fleet, _users.c.user_id == user_id)
    cols = ["user_pk", "fleet", "at", "actor_key_id", "actor_role", "actor_fleet", "what", "via"]
    done = conn(session).execute(insert(_views).from_select(cols, chosen))
    return int(done.rowcount or 0)


def prune(session: Session, *, fleet: str, before: dt.datetime) -> int:
    """Remove ``fleet``'s entries older than ``before``: how many."""
    done = conn(session).execute(
        delete(_views).where(_views.c.fleet == fleet, _views.c.at < before)
    )
    return int(done.rowcount or 0)


def list_page(
    session: Session,
    *,
    fleet: str | None,
    user_id: str | None,
    before_id: int | None,
    limit: int,
) -> list[ViewRow]:
    """Newest first: of one person (``fleet`` and ``user_id``), of a fleet, or of every fleet
    (both ``None``)."""
    stmt = (
        select(*_LISTED)
        .join(_users, _users.c.id == _views.c.user_pk)
        .outerjoin(_keys, _keys.c.id == _views.c.actor_key_id)
        .order_by(_views.c.id.desc())
        .limit(limit)
    )
    if fleet is not None:
        stmt = stmt.where(_views.c.fleet == fleet)
    if user_id is not None:
        stmt = stmt.where(_users.c.user_id == user_id)
    if before_id is not None:
        stmt = stmt.where(_views.c.id < before_id)
    return [ViewRow(*row) for row in conn(session).execute(stmt)]
