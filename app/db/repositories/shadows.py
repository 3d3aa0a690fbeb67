"""Shadows of a candidate learner (``shadows``) and the decisions they would have made
(``shadow_decisions``)."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy import case, func, insert, select, update
from sqlalchemy.orm import Session

from ..models import Decision, Episode, Shadow, ShadowDecision, User
from ._rows import columns, conn, names, record, table, values

__all__ = [
    "ShadowRow",
    "add",
    "add_decisions",
    "agreement",
    "checked",
    "done_among",
    "for_episodes",
    "latest",
    "people_with_closed",
    "running",
    "running_of",
    "set_estimate",
    "set_share",
    "stop",
]


@dataclass(slots=True)
class ShadowRow:
    id: str
    fleet: str
    algorithm: str
    params: dict[str, Any]
    share: float
    salt: str
    status: str
    started_at: dt.datetime
    started_by: str
    stopped_at: dt.datetime | None
    stopped_by: str | None
    checked_until: dt.datetime
    estimate: dict[str, Any] | None
    estimated_at: dt.datetime | None


_shadows = table(Shadow)
_decisions = table(ShadowDecision)
_episodes = table(Episode)
_users = table(User)
_COLS = columns(_shadows, ShadowRow)


def add(session: Session, row: ShadowRow) -> None:
    conn(session).execute(insert(_shadows).values(**values(row, names(ShadowRow))))


def latest(session: Session, fleet: str) -> ShadowRow | None:
    s = _shadows.c
    stmt = select(*_COLS).where(s.fleet == fleet).order_by(s.started_at.desc(), s.id.desc())
    return record(ShadowRow, conn(session).execute(stmt.limit(1)).first())


def running(session: Session) -> list[ShadowRow]:
    stmt = select(*_COLS).where(_shadows.c.status == "running").order_by(_shadows.c.fleet)
    return [ShadowRow(*r) for r in conn(session).execute(stmt)]


def running_of(session: Session, fleet: str) -> ShadowRow | None:
    s = _shadows.c
    stmt = select(*_COLS).where(s.fleet == fleet, s.status == "running")
    return record(ShadowRow, conn(session).execute(stmt).first())


def set_share(session: Session, shadow_id: str, share: float) -> None:
    conn(session).execute(update(_shadows).where(_shadows.c.id == shadow_id).values(share=share))


def stop(session: Session, shadow_id: str, *, by: str, now: dt.datetime) -> bool:
    s = _shadows.c
    done = conn(session).execute(
        update(_shadows)
        .where(s.id == shadow_id, s.status == "running")
        .values(status="stopped", stopped_at=now, stopped_by=by)
    )
    return bool(done.rowcount)


def checked(session: Session, shadow_id: str, until: dt.datetime) -> None:
    conn(session).execute(
        update(_shadows).where(_shadows.c.id == shadow_id).values(checked_until=until)
    )


def set_estimate(
    session: Session, shadow_id: str, estimate: dict[str, Any], *, at: dt.datetime
) -> None:
    conn(session).execute(
        update(_shadows)
        .where(_shadows.c.id == shadow_id)
        .values(estimate=estimate, estimated_at=at)
    )


def people_with_closed(
    session: Session, fleet: str, *, after: dt.datetime, upto: dt.datetime
) -> list[int]:
    """The fleet's people with an episode closed in (``after``, ``upto``]."""
    e, u = _episodes.c, _users.c
    stmt = (
        select(e.user_pk)
        .join(_users, u.id == e.user_pk)
        .where(u.fleet == fleet, e.status == "closed", e.closed_at > after, e.closed_at <= upto)
        .distinct()
    )
    return sorted(int(r[0]) for r in conn(session).execute(stmt))


def done_among(session: Session, shadow_id: str, decision_ids: list[str]) -> set[str]:
    """Which of ``decision_ids`` the shadow has decided at (by the primary key: a lookup per
    decision, whatever the shadow has stored)."""
    d = _decisions.c
    found: set[str] = set()
    for i in range(0, len(decision_ids), 500):
        stmt = select(d.decision_id).where(
            d.shadow_id == shadow_id, d.decision_id.in_(decision_ids[i : i + 500])
        )
        found.update(r[0] for r in conn(session).execute(stmt))
    return found


def add_decisions(session: Session, rows: list[dict[str, Any]]) -> None:
    if rows:
        conn(session).execute(insert(_decisions), rows)


def agreement(session: Session, shadow_id: str) -> tuple[int, int, float, int]:
    """(decisions, those where the candidate drew the robot's action, the mean of its
    probability of the robot's action, people)."""
    d = _decisions.c
    row = (
        conn(session)
        .execute(
            select(
                func.count(),
                func.coalesce(func.sum(case((d.agrees, 1), else_=0)), 0),
                func.coalesce(func.avg(d.logged_probability), 0.0),
                func.count(func.distinct(d.user_pk)),
            ).where(d.shadow_id == shadow_id)
        )
        .one()
    )
    return int(row[0]), int(row[1]), float(row[2]), int(row[3])


def for_episodes(session: Session, episode_ids: list[str]) -> dict[str, list[dict[str, Any]]]:
    """The shadow decisions made at the decisions of these episodes, by episode (a person's
    export)."""
    if not episode_ids:
        return {}
    d, x = _decisions.c, table(Decision).c
    stmt = (
        select(
            x.episode_id,
            x.position,
            d.shadow_id,
            d.decided_at,
            d.action,
            d.probabilities,
            d.logged_probability,
            d.agrees,
        )
        .join(table(Decision), x.id == d.decision_id)
        .where(x.episode_id.in_(episode_ids))
        .order_by(x.episode_id, x.position, d.shadow_id)
    )
    out: dict[str, list[dict[str, Any]]] = {}
    for row in conn(session).execute(stmt):
        out.setdefault(row[0], []).append(
            {
                "position": row[1],
                "shadow_id": row[2],
                "decided_at": row[3],
                "action": row[4],
                "probabilities": row[5],
                "logged_probability": row[6],
                "agrees": bool(row[7]),
            }
        )
    return out
