"""The fleet-mission aggregate: the versions of each fleet's mission (never changed, never
removed; the highest version is in force)."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy import func, insert, select, update
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from ..models import Episode, FleetMission, LearnerModel, User
from ._rows import conn, names, table

__all__ = [
    "MissionRow",
    "add",
    "add_first",
    "by_change",
    "get",
    "latest_version",
    "list_versions",
    "lock_latest",
    "models_behind",
    "open_episodes",
    "set_document",
]


@dataclass(slots=True)
class MissionRow:
    fleet: str
    version: int
    name: str
    fingerprint: str
    document: dict[str, Any]
    renames: dict[str, Any] | None
    change_id: str | None
    request_hash: str | None
    response: dict[str, Any] | None
    actor_key_id: str | None
    created_at: dt.datetime


_missions = table(FleetMission)
_NAMES = names(MissionRow)
_COLS = [_missions.c[name] for name in _NAMES]


def _row(row: Any) -> MissionRow | None:
    return None if row is None else MissionRow(*row)


def get(session: Session, fleet: str, version: int) -> MissionRow | None:
    return _row(
        conn(session)
        .execute(select(*_COLS).where(_missions.c.fleet == fleet, _missions.c.version == version))
        .first()
    )


def latest_version(session: Session, fleet: str) -> int | None:
    """The version in force (``None``: the fleet has none stored, it uses the default)."""
    found: int | None = (
        conn(session)
        .execute(select(func.max(_missions.c.version)).where(_missions.c.fleet == fleet))
        .scalar()
    )
    return found


def lock_latest(session: Session, fleet: str) -> None:
    """Lock the fleet's mission in force for the rest of the transaction: a mission change and
    the creation of a user in the fleet take this lock first, so a new user is never laid out
    for a version being replaced. (SQLite: its write transactions already hold the database's
    write lock.) Read the version afterwards with :func:`latest_version`: on PostgreSQL a
    statement that waited for the lock sees only the row it locked, not a version added
    meanwhile."""
    if conn(session).dialect.name != "postgresql":
        return
    newest = select(func.max(_missions.c.version)).where(_missions.c.fleet == fleet)
    conn(session).execute(
        select(_missions.c.id)
        .where(_missions.c.fleet == fleet, _missions.c.version == newest.scalar_subquery())
        .with_for_update()
    )


def add_first(session: Session, row: MissionRow) -> None:
    """Store a fleet's version 1 unless it has one (two first users at once: one stores it)."""
    c = conn(session)
    dialect = postgresql if c.dialect.name == "postgresql" else sqlite
    c.execute(
        dialect.insert(_missions)
        .values({name: getattr(row, name) for name in _NAMES})
        .on_conflict_do_nothing(index_elements=["fleet", "version"])
    )


def add(session: Session, row: MissionRow) -> None:
    conn(session).execute(insert(_missions).values({name: getattr(row, name) for name in _NAMES}))


def set_document(session: Session, fleet: str, version: int, document: dict[str, Any]) -> None:
    """Replace a version's document by one of the same fingerprint: only its display fields
    (labels, time zone) may differ, which learning never reads."""
    conn(session).execute(
        update(_missions)
        .where(_missions.c.fleet == fleet, _missions.c.version == version)
        .values(document=document)
    )


def by_change(session: Session, fleet: str, change_id: str) -> MissionRow | None:
    return _row(
        conn(session)
        .execute(
            select(*_COLS).where(_missions.c.fleet == fleet, _missions.c.change_id == change_id)
        )
        .first()
    )


def list_versions(session: Session, fleet: str) -> list[MissionRow]:
    """Every version of the fleet's mission, newest first."""
    return [
        MissionRow(*row)
        for row in conn(session).execute(
            select(*_COLS).where(_missions.c.fleet == fleet).order_by(_missions.c.version.desc())
        )
    ]


_users, _models, _episodes = table(User), table(LearnerModel), table(Episode)


def models_behind(session: Session, fleet: str, version: int) -> list[int]:
    """The users of ``fleet`` whose models are laid out for an older version than ``version``,
    by their number (the order every multi-user lock takes)."""
    return list(
        conn(session)
        .execute(
            select(_users.c.id)
            .join(_models, _models.c.user_pk == _users.c.id)
            .where(_users.c.fleet == fleet, _models.c.mission_version < version)
            .order_by(_users.c.id)
        )
        .scalars()
    )


def open_episodes(session: Session, fleet: str) -> int:
    """How many episodes of ``fleet``'s users are open (a change of mission interrupts them)."""
    return int(
        conn(session)
        .execute(
            select(func.count())
            .select_from(_episodes.join(_users, _episodes.c.user_pk == _users.c.id))
            .where(_users.c.fleet == fleet, _episodes.c.status == "open")
        )
        .scalar_one()
    )
