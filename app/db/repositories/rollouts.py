"""Rollouts of a candidate learner (``rollouts``) and the people's stored arms
(``rollout_arms``)."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy import func, insert, select, update
from sqlalchemy.orm import Session

from ..models import Episode, Rollout, RolloutArm, User
from ._rows import columns, conn, names, record, table, values

__all__ = [
    "ArmRow",
    "RolloutRow",
    "add",
    "add_arm",
    "arm",
    "arm_of",
    "arms",
    "arms_of_user",
    "end",
    "latest",
    "latest_of",
    "lock_running",
    "moved",
    "owe_moves",
    "owed",
    "returns",
    "running_fleets",
    "set_arm",
    "set_share",
]


@dataclass(slots=True)
class RolloutRow:
    id: str
    fleet: str
    algorithm: str
    params: dict[str, Any]
    share: float
    salt: str
    status: str
    started_at: dt.datetime
    started_by: str
    ended_at: dt.datetime | None
    ended_by: str | None
    end_reason: str | None


@dataclass(slots=True)
class ArmRow:
    rollout_id: str
    user_pk: int
    arm: str
    assigned_at: dt.datetime
    previous_algorithm: str
    previous_params: dict[str, Any]
    pending: bool = False
    served_since: dt.datetime | None = None


_rollouts = table(Rollout)
_arms = table(RolloutArm)
_users = table(User)
_episodes = table(Episode)
_COLS = columns(_rollouts, RolloutRow)
_ARM_COLS = columns(_arms, ArmRow)


def add(session: Session, row: RolloutRow) -> None:
    conn(session).execute(insert(_rollouts).values(**values(row, names(RolloutRow))))


def latest(session: Session, fleet: str) -> RolloutRow | None:
    """The fleet's newest rollout (running or ended), if any."""
    r = _rollouts.c
    stmt = select(*_COLS).where(r.fleet == fleet).order_by(r.started_at.desc(), r.id.desc())
    return record(RolloutRow, conn(session).execute(stmt.limit(1)).first())


def lock_running(session: Session, fleet: str, *, lock: bool = True) -> RolloutRow | None:
    """The fleet's running rollout, locked for the rest of the transaction (PostgreSQL; not
    with ``lock=False``, in a read transaction)."""
    r = _rollouts.c
    stmt = select(*_COLS).where(r.fleet == fleet, r.status == "running")
    if lock and conn(session).dialect.name == "postgresql":
        stmt = stmt.with_for_update()
    return record(RolloutRow, conn(session).execute(stmt).first())


def running_fleets(session: Session) -> list[str]:
    r = _rollouts.c
    return [row[0] for row in conn(session).execute(select(r.fleet).where(r.status == "running"))]


def set_share(session: Session, rollout_id: str, share: float) -> None:
    conn(session).execute(update(_rollouts).where(_rollouts.c.id == rollout_id).values(share=share))


def end(
    session: Session, rollout_id: str, *, status: str, by: str, reason: str | None, now: dt.datetime
) -> bool:
    """End a running rollout: whether it was still running."""
    r = _rollouts.c
    done = conn(session).execute(
        update(_rollouts)
        .where(r.id == rollout_id, r.status == "running")
        .values(status=status, ended_at=now, ended_by=by, end_reason=reason)
    )
    return bool(done.rowcount)


def add_arm(session: Session, row: ArmRow) -> None:
    conn(session).execute(insert(_arms).values(**values(row, names(ArmRow))))


def set_arm(session: Session, rollout_id: str, user_pk: int, arm: str, *, now: dt.datetime) -> None:
    """Give the person another arm: a move to its learner is owed."""
    a = _arms.c
    conn(session).execute(
        update(_arms)
        .where(a.rollout_id == rollout_id, a.user_pk == user_pk)
        .values(arm=arm, assigned_at=now, pending=True, served_since=None)
    )


def owe_moves(session: Session, rollout_id: str, arm: str) -> int:
    """Owe every person of ``arm`` a move (a promote, a roll back): how many."""
    a = _arms.c
    done = conn(session).execute(
        update(_arms).where(a.rollout_id == rollout_id, a.arm == arm).values(pending=True)
    )
    return int(done.rowcount or 0)


def owed(session: Session, *, limit: int) -> list[tuple[ArmRow, RolloutRow, str]]:
    """Arms owed a move, with their rollout and the person's id, oldest rollout first."""
    a, r = _arms.c, _rollouts.c
    stmt = (
        select(*_ARM_COLS, *_COLS, _users.c.user_id)
        .join(_rollouts, r.id == a.rollout_id)
        .join(_users, _users.c.id == a.user_pk)
        .where(a.pending.is_(True))
        .order_by(r.started_at, a.user_pk)
        .limit(limit)
    )
    n, m = len(_ARM_COLS), len(_COLS)
    return [
        (ArmRow(*row[:n]), RolloutRow(*row[n : n + m]), str(row[-1]))
        for row in conn(session).execute(stmt)
    ]


def arm(session: Session, rollout_id: str, user_pk: int) -> ArmRow | None:
    a = _arms.c
    stmt = select(*_ARM_COLS).where(a.rollout_id == rollout_id, a.user_pk == user_pk)
    return record(ArmRow, conn(session).execute(stmt).first())


def moved(session: Session, rollout_id: str, user_pk: int, *, now: dt.datetime) -> None:
    """The person's move is done: served by their arm's learner from ``now`` (or still from
    when they first were)."""
    a = _arms.c
    conn(session).execute(
        update(_arms)
        .where(a.rollout_id == rollout_id, a.user_pk == user_pk)
        .values(pending=False, served_since=func.coalesce(a.served_since, now))
    )


def arms(session: Session, rollout_id: str) -> list[tuple[ArmRow, str]]:
    """Every stored arm of the rollout, with the person's id, in the order of their numbers."""
    a = _arms.c
    stmt = (
        select(*_ARM_COLS, _users.c.user_id)
        .join(_users, _users.c.id == a.user_pk)
        .where(a.rollout_id == rollout_id)
        .order_by(a.user_pk)
    )
    return [(ArmRow(*row[:-1]), row[-1]) for row in conn(session).execute(stmt)]


def arm_of(session: Session, user_pk: int) -> tuple[ArmRow, RolloutRow] | None:
    """The person's arm in the newest rollout that assigned them, with the rollout."""
    a, r = _arms.c, _rollouts.c
    stmt = (
        select(*_ARM_COLS, *_COLS)
        .join(_rollouts, r.id == a.rollout_id)
        .where(a.user_pk == user_pk)
        .order_by(r.started_at.desc(), r.id.desc())
        .limit(1)
    )
    row = conn(session).execute(stmt).first()
    if row is None:
        return None
    n = len(_ARM_COLS)
    return ArmRow(*row[:n]), RolloutRow(*row[n:])


def returns(
    session: Session, rollout_id: str, *, until: dt.datetime | None = None
) -> list[tuple[int, str, float]]:
    """(person, arm, total reward) of every closed episode begun since the person's arm's
    learner serves them (and before ``until``, the rollout's end)."""
    a, e = _arms.c, _episodes.c
    stmt = (
        select(a.user_pk, a.arm, e.total_reward)
        .join(_episodes, e.user_pk == a.user_pk)
        .where(
            a.rollout_id == rollout_id,
            a.served_since.is_not(None),
            e.status == "closed",
            e.created_at >= a.served_since,
        )
    )
    if until is not None:
        stmt = stmt.where(e.created_at < until)
    return [(int(r[0]), str(r[1]), float(r[2])) for r in conn(session).execute(stmt)]


def arms_of_user(session: Session, user_pk: int) -> list[tuple[ArmRow, RolloutRow]]:
    """Every arm the person was given, oldest rollout first, with its rollout."""
    a, r = _arms.c, _rollouts.c
    stmt = (
        select(*_ARM_COLS, *_COLS)
        .join(_rollouts, r.id == a.rollout_id)
        .where(a.user_pk == user_pk)
        .order_by(r.started_at, r.id)
    )
    n = len(_ARM_COLS)
    return [(ArmRow(*row[:n]), RolloutRow(*row[n:])) for row in conn(session).execute(stmt)]


def latest_of(session: Session, rollout_id: str) -> RolloutRow | None:
    """The rollout as it is now."""
    stmt = select(*_COLS).where(_rollouts.c.id == rollout_id)
    return record(RolloutRow, conn(session).execute(stmt).first())
