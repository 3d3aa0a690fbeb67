"""The user aggregate: a person the fleet serves; the row is the per-user lock of every write."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy import bindparam, delete, func, insert, select, tuple_, update
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session

from ..models import Episode, LearnerModel, User
from ..session import NOWAIT, LockBusy
from ._rows import Prepared, columns, conn, record, table

__all__ = [
    "UserRow",
    "all_ids",
    "by_pk",
    "create",
    "delete_user",
    "fleet_counts",
    "fleets_with",
    "get",
    "list_page",
    "lock",
    "lock_fleet",
    "lock_owner",
    "save_counters",
    "save_profile",
]


@dataclass(slots=True)
class UserRow:
    """A user: ``id`` is the deployment's number for them, ``user_id`` their fleet's id;
    ``episode_count`` and ``draws`` (decisions drawn: the position in the stream of decision
    seeds named by ``seed_key``) are the counters the write path moves."""

    id: int
    user_id: str
    fleet: str
    display_name: str | None
    algorithm: str
    params: dict[str, Any]
    created_at: dt.datetime
    episode_count: int
    draws: int
    seed_key: str
    fleet_prior: bool


_users = table(User)
_models = table(LearnerModel)
_episodes = table(Episode)
_COLS = columns(_users, UserRow)
_GET = select(*_COLS).where(
    _users.c.fleet == bindparam("fleet"), _users.c.user_id == bindparam("user_id")
)
# PostgreSQL: the row lock is the per-user lock. SQLite ignores FOR UPDATE: its write
# transactions are BEGIN IMMEDIATE, which already hold the database's single write lock.
_LOCK = Prepared(_GET.with_for_update())
_OWNER_OF = select(*_COLS).where(
    _users.c.id
    == select(_episodes.c.user_pk)
    .where(_episodes.c.id == bindparam("episode_id"))
    .scalar_subquery()
)
_LOCK_OWNER = Prepared(_OWNER_OF.with_for_update())
# In a session that must not wait (app.db.session.NOWAIT): the lock only if it is free at once.
_LOCK_NOWAIT = Prepared(_GET.with_for_update(nowait=True))
_LOCK_OWNER_NOWAIT = Prepared(_OWNER_OF.with_for_update(nowait=True))
_LOCK_NOT_AVAILABLE = "55P03"  # PostgreSQL's lock_not_available
_SAVE_COUNTERS = Prepared(update(_users).where(_users.c.id == bindparam("b_id")), keyed=True)


def get(session: Session, fleet: str, user_id: str) -> UserRow | None:
    return record(
        UserRow, conn(session).execute(_GET, {"fleet": fleet, "user_id": user_id}).first()
    )


def by_pk(session: Session, user_pk: int) -> UserRow | None:
    """The user of number ``user_pk``."""
    return record(
        UserRow, conn(session).execute(select(*_COLS).where(_users.c.id == user_pk)).first()
    )


def _locked(
    session: Session, waiting: Prepared, at_once: Prepared, params: dict[str, Any]
) -> UserRow | None:
    if not session.info.get(NOWAIT):
        return record(UserRow, waiting.first(session, params))
    try:
        return record(UserRow, at_once.first(session, params))
    except OperationalError as exc:
        if getattr(exc.orig, "sqlstate", None) == _LOCK_NOT_AVAILABLE:
            raise LockBusy from None
        raise


def lock(session: Session, fleet: str, user_id: str) -> UserRow | None:
    """The user, locked for the rest of the transaction (``None``: no such user). In a session
    that must not wait (``NOWAIT``), :class:`LockBusy` if another transaction holds it."""
    return _locked(session, _LOCK, _LOCK_NOWAIT, {"fleet": fleet, "user_id": user_id})


def lock_fleet(session: Session, fleet: str) -> None:
    """Lock every user of ``fleet`` for the rest of the transaction, in the order of their
    numbers (a mission change: no write of the fleet's users runs beside it)."""
    if conn(session).dialect.name == "postgresql":
        conn(session).execute(
            select(_users.c.id)
            .where(_users.c.fleet == fleet)
            .order_by(_users.c.id)
            .with_for_update()
        )


def lock_owner(session: Session, episode_id: str) -> UserRow | None:
    """The user who owns an episode, locked as by :func:`lock`; ``None`` if no episode.

    The lock comes first and alone: on PostgreSQL a statement that waited for it sees the rows
    committed by the previous holder only if it starts after the wait (READ COMMITTED), so the
    episode is read by the next statement.
    """
    return _locked(session, _LOCK_OWNER, _LOCK_OWNER_NOWAIT, {"episode_id": episode_id})


def create(
    session: Session,
    *,
    user_id: str,
    fleet: str,
    algorithm: str,
    params: dict[str, Any],
    display_name: str | None,
    state: dict[str, Any],
    mission_version: int,
    now: dt.datetime,
    fleet_prior: bool = True,
    base: tuple[dict[str, Any], int] | None = None,
) -> bool:
    """Insert the user and its model unless the fleet has that id; True when inserted. The
    model starts as ``state``: a fresh learner, or with ``base`` (the prior's document, its
    contributors) the fleet's prior, kept as the model's base.

    ``ON CONFLICT DO NOTHING`` makes two robots creating the same user at once safe: one wins,
    the other sees the winner's row when it locks it. The user's decisions are seeded by
    ``fleet/user_id`` (the users of the deployment before fleets had ids of their own keep
    their user id).
    """
    c = conn(session)
    dialect = postgresql if c.dialect.name == "postgresql" else sqlite
    stmt = (
        dialect.insert(_users)
        .values(
            user_id=user_id,
            fleet=fleet,
            algorithm=algorithm,
            params=params,
            display_name=display_name,
            created_at=now,
            episode_count=0,
            draws=0,
            seed_key=f"{fleet}/{user_id}",
            fleet_prior=fleet_prior,
        )
        .on_conflict_do_nothing(index_elements=["fleet", "user_id"])
        .returning(_users.c.id)
    )
    made = c.execute(stmt).first()
    if made is None:
        return False
    c.execute(
        insert(_models).values(
            user_pk=made[0],
            version=0,
            state=state,
            base_state=None if base is None else base[0],
            base_version=0,
            episode_offset=0,
            mission_version=mission_version,
            base_mission_version=mission_version,
            updated_at=now,
            base_origin="fresh" if base is None else "fleet_prior",
            base_contributors=None if base is None else base[1],
        )
    )
    return True


def save_counters(session: Session, user: UserRow) -> None:
    _SAVE_COUNTERS.run(
        session, {"b_id": user.id, "episode_count": user.episode_count, "draws": user.draws}
    )


def save_profile(session: Session, user: UserRow) -> None:
    """Store the display name, the learner's algorithm and parameters, and whether the person
    takes part in the fleet's prior."""
    conn(session).execute(
        update(_users)
        .where(_users.c.id == user.id)
        .values(
            display_name=user.display_name,
            algorithm=user.algorithm,
            params=user.params,
            fleet_prior=user.fleet_prior,
        )
    )


def list_page(
    session: Session, *, fleet: str | None, after: tuple[str, str] | None, limit: int
) -> list[UserRow]:
    """Users of one fleet by user id, or of every fleet (``None``) by fleet and user id; those
    after ``after`` (fleet, user id)."""
    stmt = select(*_COLS).order_by(_users.c.fleet, _users.c.user_id).limit(limit)
    if fleet is not None:
        stmt = stmt.where(_users.c.fleet == fleet)
    if after is not None:
        stmt = stmt.where(tuple_(_users.c.fleet, _users.c.user_id) > tuple_(*after))
    return [UserRow(*row) for row in conn(session).execute(stmt)]


def delete_user(session: Session, user: UserRow) -> None:
    """The user, its model, history and journal (the foreign keys cascade)."""
    conn(session).execute(delete(_users).where(_users.c.id == user.id))


def fleets_with(session: Session, user_id: str) -> list[str]:
    """The fleets that have a user of this id."""
    stmt = select(_users.c.fleet).where(_users.c.user_id == user_id).order_by(_users.c.fleet)
    return [fleet for (fleet,) in conn(session).execute(stmt)]


def all_ids(session: Session) -> list[tuple[str, str]]:
    """(fleet, user id) of every user."""
    stmt = select(_users.c.fleet, _users.c.user_id).order_by(_users.c.fleet, _users.c.user_id)
    return [(f, u) for f, u in conn(session).execute(stmt)]


def fleet_counts(session: Session) -> dict[str, tuple[int, int]]:
    """Per fleet that has users: (users, episodes)."""
    stmt = select(
        _users.c.fleet, func.count(), func.coalesce(func.sum(_users.c.episode_count), 0)
    ).group_by(_users.c.fleet)
    return {fleet: (int(n), int(e)) for fleet, n, e in conn(session).execute(stmt)}
