"""Who looked at a person's data (docs/privacy.md, "Who looked").

Every read of a person's data by a staff or admin key is recorded: the API's reads of the
person, their model, statistics, profile, corrections, episodes and export, and the console's
pages of them. A robot reads on every event and is not recorded read by read; neither is the
list of a fleet's people, nor the reading of this record itself. An entry is the person's data:
it goes when they are erased, and entries older than ``ATTUNE_VIEW_LOG_DAYS`` go as new ones
of the fleet are added.
"""

from __future__ import annotations

import datetime as dt

from sqlalchemy.orm import Session

from app.db.repositories import views as repo
from app.db.session import Database
from app.db.types import utcnow
from app.errors import NotFound, ValidationFailed
from app.schemas.audit import ViewActor, ViewList, ViewOut
from app.schemas.common import position_of
from app.settings import Settings

from .auth import require_manager
from .context import Principal
from .users import fleet_of, visible_user

__all__ = ["READS", "add", "list_views", "record", "view_out"]

READS = (
    "user",
    "model",
    "stats",
    "profile",
    "corrections",
    "episodes",
    "episode",
    "export",
    "subject",
    "changes",
    "evaluation",
    "console.profile",
    "console.details",
    "console.why",
    "console.episodes",
    "console.trace",
)


def add(
    session: Session,
    settings: Settings,
    principal: Principal,
    *,
    fleet: str,
    user_id: str,
    what: str,
    via: str = "api",
) -> None:
    """Record, in ``session``'s write transaction, that ``principal`` read ``what`` of the
    person (nothing for a robot key), and remove the fleet's entries older than the window."""
    if not principal.manages:
        return
    if what not in READS:
        raise ValueError(f"unknown read {what!r}")
    now = utcnow()
    repo.add(
        session,
        fleet=fleet,
        user_id=user_id,
        at=now,
        actor=(principal.key_id, principal.role, principal.fleet),
        what=what,
        via=via,
    )
    if settings.view_log_days:
        repo.prune(session, fleet=fleet, before=now - dt.timedelta(days=settings.view_log_days))


def record(
    db: Database,
    settings: Settings,
    principal: Principal,
    *,
    user_id: str,
    fleet: str | None,
    what: str,
    via: str = "api",
) -> None:
    """:func:`add` in a write transaction of its own, for a read that ran in a read-only one
    (before its answer leaves: a read whose record cannot be stored is not answered).
    ``fleet``: as the request named it (an admin's ``?fleet=``, else the caller's own)."""
    if not principal.manages:
        return
    in_fleet = fleet_of(principal, fleet, user_id)
    with db.transaction(write=True) as session:
        add(session, settings, principal, fleet=in_fleet, user_id=user_id, what=what, via=via)


def view_out(row: repo.ViewRow) -> ViewOut:
    return ViewOut(
        id=str(row.id),
        at=row.at,
        user_id=row.user_id,
        fleet=row.fleet,
        actor=ViewActor(
            key_id=row.actor_key_id, role=row.actor_role, fleet=row.actor_fleet, name=row.actor_name
        ),
        what=row.what,
        via=row.via,
    )


def list_views(
    session: Session,
    principal: Principal,
    *,
    limit: int,
    cursor: str | None,
    user_id: str | None = None,
    fleet: str | None = None,
) -> ViewList:
    """Who looked, newest first, a page at a time: at one person (``user_id``), or at every
    person of the caller's fleet (an admin's: of every fleet, or of ``fleet``). Staff and
    admins only."""
    require_manager(principal)
    if fleet is not None and user_id is None and not principal.sees(fleet):
        raise NotFound(f"No fleet {fleet!r} you can see.")
    before: int | None = None
    if cursor is not None:
        before = position_of(cursor)
        if before is None:
            raise ValidationFailed("cursor is not one this API returned.")
    if user_id is not None:
        listed: str | None = visible_user(session, principal, user_id, fleet=fleet).fleet
    elif principal.is_admin:
        listed = fleet
    else:
        listed = principal.fleet
    rows = repo.list_page(session, fleet=listed, user_id=user_id, before_id=before, limit=limit + 1)
    more = len(rows) > limit
    return ViewList(
        items=[view_out(r) for r in rows[:limit]],
        next_cursor=str(rows[limit - 1].id) if more else None,
    )
