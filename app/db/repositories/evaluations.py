"""Evaluations of candidate learners (``evaluations``): a fleet's jobs, taken by the process that
runs one with a conditional ``UPDATE``, their progress and heartbeat, and their results. Each
write of a runner is its transaction's only work."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy import and_, insert, or_, select, update
from sqlalchemy.orm import Session

from ..models import Evaluation
from ._rows import columns, conn, names, record, table, values

__all__ = [
    "ACTIVE",
    "EvaluationRow",
    "active",
    "add",
    "beat_queued",
    "by_id",
    "by_request",
    "claim",
    "fail_queued",
    "finish",
    "for_fleet",
    "forget_person",
    "get",
    "progress",
    "request_cancel",
    "results_naming",
    "set_result",
    "stop_stale",
]

ACTIVE = ("queued", "running")


@dataclass(slots=True)
class EvaluationRow:
    id: str
    fleet: str
    request_id: str
    request_hash: str
    request: dict[str, Any]
    status: str
    actor_key_id: str
    actor_role: str
    created_at: dt.datetime
    started_at: dt.datetime | None
    finished_at: dt.datetime | None
    heartbeat_at: dt.datetime
    holder: str | None
    done_people: int
    total_people: int | None
    cancel_requested: bool
    error: str | None
    result: dict[str, Any] | None


_evaluations = table(Evaluation)
_COLS = columns(_evaluations, EvaluationRow)
_NAMES = names(EvaluationRow)


def add(session: Session, row: EvaluationRow) -> None:
    conn(session).execute(insert(_evaluations).values(**values(row, _NAMES)))


def get(session: Session, fleet: str, evaluation_id: str) -> EvaluationRow | None:
    e = _evaluations.c
    stmt = select(*_COLS).where(e.fleet == fleet, e.id == evaluation_id)
    return record(EvaluationRow, conn(session).execute(stmt).first())


def by_id(session: Session, evaluation_id: str) -> EvaluationRow | None:
    stmt = select(*_COLS).where(_evaluations.c.id == evaluation_id)
    return record(EvaluationRow, conn(session).execute(stmt).first())


def by_request(session: Session, fleet: str, request_id: str) -> EvaluationRow | None:
    e = _evaluations.c
    stmt = select(*_COLS).where(e.fleet == fleet, e.request_id == request_id)
    return record(EvaluationRow, conn(session).execute(stmt).first())


def active(session: Session, fleet: str) -> EvaluationRow | None:
    """The fleet's queued or running job, if any (there is at most one)."""
    e = _evaluations.c
    stmt = select(*_COLS).where(e.fleet == fleet, e.status.in_(ACTIVE))
    return record(EvaluationRow, conn(session).execute(stmt).first())


def for_fleet(
    session: Session, fleet: str, *, before: EvaluationRow | None, limit: int
) -> list[EvaluationRow]:
    """The fleet's jobs, newest first, after ``before`` (the last of the previous page)."""
    e = _evaluations.c
    stmt = select(*_COLS).where(e.fleet == fleet)
    if before is not None:
        stmt = stmt.where(
            or_(
                e.created_at < before.created_at,
                and_(e.created_at == before.created_at, e.id < before.id),
            )
        )
    stmt = stmt.order_by(e.created_at.desc(), e.id.desc()).limit(limit)
    return [EvaluationRow(*r) for r in conn(session).execute(stmt)]


def stop_stale(
    session: Session, *, before: dt.datetime, now: dt.datetime, fleet: str | None = None
) -> list[str]:
    """Mark failed every queued or running job (of ``fleet``) whose heartbeat is older than
    ``before``: the process that had it stopped. Their ids."""
    e = _evaluations.c
    where = [e.status.in_(ACTIVE), e.heartbeat_at < before]
    if fleet is not None:
        where.append(e.fleet == fleet)
    stmt = (
        update(_evaluations)
        .where(*where)
        .values(
            status="failed",
            finished_at=now,
            error="The process that ran it stopped before it finished; start it again.",
        )
        .returning(e.id)
    )
    return [r[0] for r in conn(session).execute(stmt)]


def claim(session: Session, evaluation_id: str, *, holder: str, now: dt.datetime) -> bool:
    """Take a queued job for ``holder``: whether it was still queued (not cancelled, not
    taken, not yet stale)."""
    e = _evaluations.c
    done = conn(session).execute(
        update(_evaluations)
        .where(e.id == evaluation_id, e.status == "queued")
        .values(status="running", holder=holder, started_at=now, heartbeat_at=now)
    )
    return bool(done.rowcount)


def progress(
    session: Session,
    evaluation_id: str,
    *,
    holder: str,
    done: int,
    total: int,
    now: dt.datetime,
) -> tuple[bool, bool]:
    """Write how far ``holder``'s job got, and its heartbeat: (still ``holder``'s and running,
    cancel asked)."""
    e = _evaluations.c
    row = (
        conn(session)
        .execute(
            update(_evaluations)
            .where(e.id == evaluation_id, e.holder == holder, e.status == "running")
            .values(done_people=done, total_people=total, heartbeat_at=now)
            .returning(e.cancel_requested)
        )
        .first()
    )
    return (row is not None, bool(row[0]) if row is not None else False)


def finish(
    session: Session,
    evaluation_id: str,
    *,
    holder: str,
    status: str,
    now: dt.datetime,
    result: dict[str, Any] | None = None,
    error: str | None = None,
) -> bool:
    """End ``holder``'s running job as ``status``: whether it was still theirs."""
    e = _evaluations.c
    done = conn(session).execute(
        update(_evaluations)
        .where(e.id == evaluation_id, e.holder == holder, e.status == "running")
        .values(status=status, finished_at=now, heartbeat_at=now, result=result, error=error)
    )
    return bool(done.rowcount)


def request_cancel(session: Session, evaluation_id: str, *, now: dt.datetime) -> None:
    """Cancel a job: a queued one at once, a running one at its runner's next step."""
    e = _evaluations.c
    c = conn(session)
    c.execute(
        update(_evaluations)
        .where(e.id == evaluation_id, e.status == "queued")
        .values(status="cancelled", finished_at=now, cancel_requested=True)
    )
    c.execute(
        update(_evaluations)
        .where(e.id == evaluation_id, e.status == "running")
        .values(cancel_requested=True)
    )


def results_naming(session: Session, fleet: str) -> list[tuple[str, dict[str, Any]]]:
    """(id, result) of the fleet's finished jobs (whose results may name people)."""
    e = _evaluations.c
    stmt = select(e.id, e.result).where(e.fleet == fleet, e.status == "done")
    return [(r[0], r[1]) for r in conn(session).execute(stmt) if r[1]]


def set_result(session: Session, evaluation_id: str, result: dict[str, Any]) -> None:
    e = _evaluations.c
    conn(session).execute(update(_evaluations).where(e.id == evaluation_id).values(result=result))


def beat_queued(session: Session, evaluation_ids: list[str], *, now: dt.datetime) -> None:
    """Keep the heartbeat of jobs waiting their turn in a runner."""
    e = _evaluations.c
    conn(session).execute(
        update(_evaluations)
        .where(e.id.in_(evaluation_ids), e.status == "queued")
        .values(heartbeat_at=now)
    )


def fail_queued(session: Session, evaluation_id: str, *, error: str, now: dt.datetime) -> None:
    """End a job that never started (its runner stops)."""
    e = _evaluations.c
    conn(session).execute(
        update(_evaluations)
        .where(e.id == evaluation_id, e.status == "queued")
        .values(status="failed", finished_at=now, error=error)
    )


def forget_person(session: Session, fleet: str, user_id: str) -> int:
    """Remove an erased person's row from every stored result of their fleet: how many
    results named them."""
    n = 0
    for evaluation_id, result in results_naming(session, fleet):
        persons = result.get("persons", [])
        kept = [p for p in persons if p.get("user_id") != user_id]
        if len(kept) != len(persons):
            set_result(session, evaluation_id, {**result, "persons": kept})
            n += 1
    return n
