"""Evaluations of candidate learners as background jobs of the service
(``POST /v1/admin/fleets/{fleet}/evaluations``): the estimate of :func:`app.services.evaluation.
evaluate_fleet`, started by a fleet's staff or an admin, run by the worker that took the request
while the robots go on being served, and read back when it is done.

- **One at a time per fleet.** A fleet has at most one job queued or running: the database says
  so to every worker and instance (a partial unique index), and a second start gets 409 naming
  the job in the way. A job is idempotent on the fleet's ``request_id``: the same request again
  gets the same job (``Idempotent-Replay: true``), another request under the same id 409.
- **Bounded.** At most :data:`MAX_CANDIDATES` candidates; each worker runs one job at a time
  (the others wait, queued, in the order they came); a job that runs longer than
  ``ATTUNE_EVALUATION_MAX_MINUTES`` is stopped and marked failed. The evaluation reads a page of
  people at a time and each person in a short read transaction of their own (nothing is held
  between two people), so a job never holds the database's write turn.
- **Progress and cancel.** The runner writes how many people it has done, and its heartbeat, at
  most every :data:`BEAT_EVERY` (in a transaction of its own, which also tells it whether
  cancelling was asked); a cancelled job stops after the person in hand.
- **A runner that stops.** A worker that stops (a deploy's drain, ``kill -9``, a lost machine)
  leaves its job queued or running with a heartbeat that no longer moves: once it is older than
  :data:`STALE_AFTER`, the job reads as failed ("the process that ran it stopped"), and the
  next start for the fleet marks it so. A drained worker marks its own job failed at once.
- **Audited, and who looked.** Starting (``evaluation.start``) and cancelling
  (``evaluation.cancel``) are audit entries; a result's per-person rows are a person's data:
  reading them is recorded as a look at each person named (``evaluation``), and a person's
  erasure removes their row from every stored result (the fleet's figures, made with their
  episodes among all the others', stay).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import logging
import queue
import secrets
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import evaluations as repo
from app.db.repositories import users as users_repo
from app.db.repositories.evaluations import EvaluationRow
from app.db.session import Database
from app.db.types import utcnow
from app.errors import Conflict, Forbidden, NotFound, ValidationFailed
from app.learning.offpolicy import DEFAULT_ESTIMATOR, ESTIMATORS
from app.logs import FIELDS

from . import audit, views
from .auth import require_manager
from .context import Principal, ServiceContext, after_commit
from .evaluation import CandidateSpec, candidate_spec, evaluate_fleet
from .leases import holder_name

__all__ = [
    "BEAT_EVERY",
    "MAX_CANDIDATES",
    "STALE_AFTER",
    "EvaluationRunner",
    "cancel",
    "get",
    "list_for_fleet",
    "person_rows",
    "run_job",
    "start",
]

log = logging.getLogger("attune.evaluations")

MAX_CANDIDATES = 5
"""The most candidates one evaluation estimates."""
BEAT_EVERY = 1.0
"""Seconds between two writes of a running job's progress and heartbeat (at most)."""
STALE_AFTER = dt.timedelta(minutes=5)
"""A queued or running job whose heartbeat is older than this was left by a process that
stopped."""
_STOPPED = "The process that ran it stopped before it finished; start it again."
_DRAINED = "The service stopped (a restart or a deploy) while it ran; start it again."
_FAILED = "An internal error stopped it (the service's log says which); start it again."


# ---------------------------------------------------------------------------------------------
# What staff ask


@dataclass(frozen=True)
class Asked:
    """What a start asks for, validated."""

    request_id: str
    candidates: tuple[CandidateSpec, ...]
    since: dt.datetime | None
    until: dt.datetime | None
    estimator: str

    def document(self) -> dict[str, Any]:
        return {
            "candidates": [
                {"algorithm": c.algorithm, "params": dict(c.params)}
                # (fleet_prior only when given: a request stored before it existed digests alike)
                | ({} if c.fleet_prior is None else {"fleet_prior": c.fleet_prior})
                for c in self.candidates
            ],
            "since": None if self.since is None else self.since.isoformat(),
            "until": None if self.until is None else self.until.isoformat(),
            "estimator": self.estimator,
        }

    def digest(self) -> str:
        doc = {"request_id": self.request_id, **self.document()}
        return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def asked(
    request_id: str,
    candidates: Sequence[Mapping[str, Any]],
    *,
    since: dt.datetime | None,
    until: dt.datetime | None,
    estimator: str | None,
) -> Asked:
    """The request, checked: :class:`ValidationFailed` naming the field that is wrong."""
    if not candidates:
        raise ValidationFailed(
            "candidates: give at least one learner to estimate.",
            fields=[{"loc": ["body", "candidates"], "msg": "at least one candidate"}],
        )
    if len(candidates) > MAX_CANDIDATES:
        raise ValidationFailed(
            f"candidates: at most {MAX_CANDIDATES} in one evaluation; got {len(candidates)}.",
            fields=[{"loc": ["body", "candidates"], "msg": f"at most {MAX_CANDIDATES}"}],
        )
    specs: list[CandidateSpec] = []
    for i, given in enumerate(candidates):
        try:
            spec = candidate_spec(
                given["algorithm"], given.get("params") or {}, given.get("fleet_prior")
            )
        except ValueError as exc:
            raise ValidationFailed(
                f"candidates[{i}]: {exc}",
                fields=[{"loc": ["body", "candidates", i], "msg": str(exc)}],
            ) from None
        if spec.key in {s.key for s in specs}:
            raise ValidationFailed(
                f"candidates[{i}]: {spec.label} is asked twice.",
                fields=[{"loc": ["body", "candidates", i], "msg": "asked twice"}],
            )
        specs.append(spec)
    for name, at in (("since", since), ("until", until)):
        if at is not None and at.tzinfo is None:
            raise ValidationFailed(
                f"{name} must carry an offset (RFC 3339).",
                fields=[{"loc": ["body", name], "msg": "no offset"}],
            )
    if since is not None and until is not None and until <= since:
        raise ValidationFailed(
            "until must come after since.",
            fields=[{"loc": ["body", "until"], "msg": "before since"}],
        )
    chosen = estimator or DEFAULT_ESTIMATOR
    if chosen not in ESTIMATORS:
        raise ValidationFailed(
            f"estimator must be one of {', '.join(ESTIMATORS)}; got {chosen!r}.",
            fields=[{"loc": ["body", "estimator"], "msg": "unknown estimator"}],
        )
    return Asked(request_id, tuple(specs), since, until, chosen)


def _specs(request: Mapping[str, Any]) -> list[CandidateSpec]:
    return [
        candidate_spec(c["algorithm"], c.get("params") or {}, c.get("fleet_prior"))
        for c in request["candidates"]
    ]


def _time(text: str | None) -> dt.datetime | None:
    return None if text is None else dt.datetime.fromisoformat(text)


# ---------------------------------------------------------------------------------------------
# The routes' work


def _check_fleet(principal: Principal, fleet: str) -> None:
    require_manager(principal)
    if not principal.sees(fleet):
        raise Forbidden("Staff keys evaluate and read their own fleet's evaluations only.")


def _stale(row: EvaluationRow, now: dt.datetime) -> bool:
    return row.status in repo.ACTIVE and row.heartbeat_at < now - STALE_AFTER


def out(row: EvaluationRow, *, now: dt.datetime, persons: bool = True) -> dict[str, Any]:
    """A job as the API gives it (``persons``: with the result's per-person rows)."""
    status, error = row.status, row.error
    if _stale(row, now):
        status, error = "failed", _STOPPED
    request = row.request
    result = row.result
    if result is not None and not persons:
        result = {k: v for k, v in result.items() if k != "persons"}
    return {
        "evaluation_id": row.id,
        "fleet": row.fleet,
        "request_id": row.request_id,
        "status": status,
        "candidates": [s.to_dict() for s in _specs(request)],
        "since": request.get("since"),
        "until": request.get("until"),
        "estimator": request["estimator"],
        "requested_by": {"key_id": row.actor_key_id, "role": row.actor_role},
        "created_at": row.created_at,
        "started_at": row.started_at,
        "finished_at": row.finished_at,
        "progress": {"people_done": row.done_people, "people_total": row.total_people},
        "cancel_requested": row.cancel_requested,
        "error": error,
        "result": result,
    }


def start(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    fleet: str,
    wanted: Asked,
    *,
    runner: EvaluationRunner | None,
) -> tuple[dict[str, Any], bool]:
    """Queue an evaluation of ``fleet`` (the fleet's staff, admins); the runner takes it once
    this transaction commits. (the job, replayed)."""
    _check_fleet(principal, fleet)
    digest = wanted.digest()
    now = utcnow()
    earlier = repo.by_request(session, fleet, wanted.request_id)
    if earlier is not None:
        if earlier.request_hash != digest:
            raise Conflict(
                f"request_id {wanted.request_id!r} was already used for another evaluation of "
                f"fleet {fleet!r}."
            )
        return out(earlier, now=now, persons=False), True
    if fleet not in users_repo.fleet_counts(session):
        raise NotFound(f"No fleet {fleet!r}: no person of this database is in it.")
    for stopped in repo.stop_stale(session, fleet=fleet, before=now - STALE_AFTER, now=now):
        log.warning("Evaluation %s of fleet %s marked failed: %s", stopped, fleet, _STOPPED)
    busy = repo.active(session, fleet)
    if busy is not None:
        raise Conflict(
            f"Evaluation {busy.id} of fleet {fleet!r} is {busy.status}: one evaluation of a "
            "fleet at a time. Wait for it to finish, or cancel it "
            f"(POST .../evaluations/{busy.id}/cancel)."
        )
    row = EvaluationRow(
        id=f"ev_{secrets.token_hex(16)}",
        fleet=fleet,
        request_id=wanted.request_id,
        request_hash=digest,
        request=wanted.document(),
        status="queued",
        actor_key_id=principal.key_id,
        actor_role=principal.role,
        created_at=now,
        started_at=None,
        finished_at=None,
        heartbeat_at=now,
        holder=None,
        done_people=0,
        total_people=None,
        cancel_requested=False,
        error=None,
        result=None,
    )
    repo.add(session, row)
    audit.record(
        session,
        principal,
        "evaluation.start",
        target=row.id,
        fleet=fleet,
        detail={
            "candidates": [s.key for s in wanted.candidates],
            "since": row.request["since"],
            "until": row.request["until"],
            "estimator": wanted.estimator,
        },
    )
    if runner is not None:
        after_commit(session, lambda: runner.submit(row.id))
    return out(row, now=now), False


def _visible(
    session: Session, principal: Principal, fleet: str, evaluation_id: str
) -> EvaluationRow:
    _check_fleet(principal, fleet)
    row = repo.get(session, fleet, evaluation_id)
    if row is None:
        raise NotFound(f"No evaluation {evaluation_id!r} of fleet {fleet!r}.")
    return row


def get(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    fleet: str,
    evaluation_id: str,
    *,
    persons: bool = True,
    via: str = "api",
) -> dict[str, Any]:
    """One job with its result (the fleet's staff, admins). With ``persons``, each person the
    result names is recorded as looked at (``evaluation``), in ``session``'s write
    transaction."""
    row = _visible(session, principal, fleet, evaluation_id)
    found = out(row, now=utcnow(), persons=persons)
    if persons and row.result is not None:
        for person in row.result.get("persons", []):
            views.add(
                session,
                ctx.settings,
                principal,
                fleet=fleet,
                user_id=person["user_id"],
                what="evaluation",
                via=via,
            )
    return found


def list_for_fleet(
    session: Session,
    principal: Principal,
    fleet: str,
    *,
    limit: int,
    cursor: str | None,
) -> dict[str, Any]:
    """The fleet's evaluations, newest first, without their per-person rows."""
    _check_fleet(principal, fleet)
    before = None
    if cursor is not None:
        before = repo.get(session, fleet, cursor)
        if before is None:
            raise ValidationFailed(
                "cursor names no evaluation of this fleet.",
                fields=[{"loc": ["query", "cursor"], "msg": "unknown cursor"}],
            )
    rows = repo.for_fleet(session, fleet, before=before, limit=limit + 1)
    now = utcnow()
    items = [out(r, now=now, persons=False) for r in rows[:limit]]
    more = len(rows) > limit
    return {"items": items, "next_cursor": rows[limit - 1].id if more else None}


def cancel(
    session: Session, ctx: ServiceContext, principal: Principal, fleet: str, evaluation_id: str
) -> dict[str, Any]:
    """Cancel a job (the fleet's staff, admins): a queued one at once, a running one after the
    person in hand. A job already finished is left as it is (its state is the answer)."""
    row = _visible(session, principal, fleet, evaluation_id)
    now = utcnow()
    if row.status in repo.ACTIVE and not _stale(row, now) and not row.cancel_requested:
        repo.request_cancel(session, row.id, now=now)
        audit.record(
            session, principal, "evaluation.cancel", target=row.id, fleet=fleet, detail=None
        )
        row = repo.get(session, fleet, evaluation_id) or row
    return out(row, now=now, persons=False)


def person_rows(
    session: Session, ctx: ServiceContext, principal: Principal, fleet: str, user_id: str
) -> tuple[dict[str, Any], dict[str, Any]] | None:
    """The newest finished evaluation of the fleet that holds a row for the person: (the job
    without per-person rows, the person's row), or None. Recorded as a look at the person
    (``evaluation``) when there is one."""
    _check_fleet(principal, fleet)
    before = None
    while True:
        rows = repo.for_fleet(session, fleet, before=before, limit=20)
        for row in rows:
            if row.status != "done" or not row.result:
                continue
            for person in row.result.get("persons", []):
                if person["user_id"] == user_id:
                    views.add(
                        session,
                        ctx.settings,
                        principal,
                        fleet=fleet,
                        user_id=user_id,
                        what="evaluation",
                        via="console",
                    )
                    return out(row, now=utcnow(), persons=False), person
        if len(rows) < 20:
            return None
        before = rows[-1]


# ---------------------------------------------------------------------------------------------
# Running


class _Stop(Exception):
    """The job stops here: ``status`` and ``error`` say how it ends."""

    def __init__(self, status: str, error: str | None) -> None:
        super().__init__(error or status)
        self.status, self.error = status, error


def run_job(
    db: Database,
    ctx: ServiceContext,
    evaluation_id: str,
    *,
    holder: str | None = None,
    stopping: Callable[[], bool] = lambda: False,
    clock: Callable[[], float] = time.monotonic,
) -> str | None:
    """Take the queued job and run it to its end: its final status, or None when it was no
    longer queued (cancelled, or another process took it)."""
    holder = holder or holder_name()
    with db.transaction() as session:
        claimed = repo.claim(session, evaluation_id, holder=holder, now=utcnow())
        row = repo.by_id(session, evaluation_id) if claimed else None
    if row is None:
        return None
    fields = {"evaluation_id": row.id, "fleet": row.fleet}
    log.info(
        "Evaluation %s of fleet %s started: %s.",
        row.id,
        row.fleet,
        ", ".join(s.label for s in _specs(row.request)),
        extra={FIELDS: fields},
    )
    began = clock()
    deadline = began + ctx.settings.evaluation_max_minutes * 60.0
    last = began

    def progress(done: int, total: int) -> None:
        nonlocal last
        now = clock()
        if stopping():
            raise _Stop("failed", _DRAINED)
        if now > deadline:
            raise _Stop(
                "failed",
                f"It ran longer than {ctx.settings.evaluation_max_minutes:g} minutes "
                "(ATTUNE_EVALUATION_MAX_MINUTES) and was stopped; evaluate a shorter period or "
                "fewer candidates.",
            )
        if now - last < BEAT_EVERY and done < total:
            return
        last = now
        with db.transaction() as session:
            mine, cancelled = repo.progress(
                session, row.id, holder=holder, done=done, total=total, now=utcnow()
            )
        if not mine:
            raise _Stop("lost", None)
        if cancelled:
            raise _Stop("cancelled", None)

    request = row.request
    try:
        found = evaluate_fleet(
            db,
            ctx,
            row.fleet,
            _specs(request),
            since=_time(request.get("since")),
            until=_time(request.get("until")),
            estimator=request["estimator"],
            progress=progress,
        )
        status, error, result = "done", None, found.to_dict()
    except _Stop as stop:
        if stop.status == "lost":
            log.warning(
                "Evaluation %s of fleet %s is no longer this process's (it was marked failed "
                "while its heartbeat stood still); its work is dropped.",
                row.id,
                row.fleet,
                extra={FIELDS: fields},
            )
            return None
        status, error, result = stop.status, stop.error, None
    except NotFound as exc:
        status, error, result = "failed", str(exc), None
    except Exception:
        log.exception(
            "Evaluation %s of fleet %s failed.", row.id, row.fleet, extra={FIELDS: fields}
        )
        status, error, result = "failed", _FAILED, None
    with db.transaction() as session:
        kept = repo.finish(
            session, row.id, holder=holder, status=status, now=utcnow(), result=result, error=error
        )
    seconds = clock() - began
    if not kept:
        log.warning(
            "Evaluation %s of fleet %s ended (%s) after it was marked failed elsewhere.",
            row.id,
            row.fleet,
            status,
            extra={FIELDS: fields},
        )
        return None
    log.info(
        "Evaluation %s of fleet %s %s in %.1f s%s",
        row.id,
        row.fleet,
        {"done": "finished", "cancelled": "was cancelled", "failed": "failed"}[status],
        seconds,
        f": {error}" if error else ".",
        extra={FIELDS: {**fields, "status": status, "seconds": round(seconds, 3)}},
    )
    return status


class EvaluationRunner:
    """A worker's runner of evaluations: one thread, one job at a time, in the order they came.

    :meth:`submit` hands it a job id (after the job's transaction committed). A job waiting its
    turn keeps its heartbeat fresh, so that it does not read as stale. :meth:`stop` (the
    worker's shutdown) stops the job in hand after the person in hand, marked failed."""

    def __init__(
        self,
        db: Database,
        ctx: ServiceContext,
        *,
        stopping: Callable[[], bool] = lambda: False,
    ) -> None:
        self.db, self.ctx = db, ctx
        self._stopping = stopping
        self._queue: queue.Queue[str | None] = queue.Queue()
        self._waiting: list[str] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.holder = holder_name()

    def stopping(self) -> bool:
        return self._stop.is_set() or self._stopping()

    def submit(self, evaluation_id: str) -> None:
        with self._lock:
            if self._thread is None:
                self._thread = threading.Thread(
                    target=self._loop, name="attune-evaluations", daemon=True
                )
                self._thread.start()
            self._waiting.append(evaluation_id)
        self._queue.put(evaluation_id)

    def stop(self, timeout: float = 5.0) -> bool:
        """Stop the thread: whether it ended within ``timeout`` seconds."""
        self._stop.set()
        self._queue.put(None)
        thread = self._thread
        if thread is None:
            return True
        thread.join(timeout)
        return not thread.is_alive()

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                evaluation_id = self._queue.get(timeout=BEAT_EVERY * 30)
            except queue.Empty:
                continue
            if evaluation_id is None:
                break
            with self._lock:
                if evaluation_id in self._waiting:
                    self._waiting.remove(evaluation_id)
            if self.stopping():
                self._fail_waiting([evaluation_id])
                continue
            try:
                run_job(
                    self.db,
                    self.ctx,
                    evaluation_id,
                    holder=self.holder,
                    stopping=self._beat_and_check,
                )
            except Exception:  # the database unreachable at the start or the end
                log.exception("Evaluation %s could not be run.", evaluation_id)
        with self._lock:
            left, self._waiting = list(self._waiting), []
        self._fail_waiting(left)

    def _beat_and_check(self) -> bool:
        """Called at every step of the job in hand: refresh the heartbeat of the jobs waiting
        their turn (at most every few seconds), and say whether the worker is stopping."""
        now = time.monotonic()
        if now - getattr(self, "_beaten", 0.0) >= BEAT_EVERY * 5:
            self._beaten = now
            with self._lock:
                waiting = list(self._waiting)
            if waiting:
                try:
                    with self.db.transaction() as session:
                        repo.beat_queued(session, waiting, now=utcnow())
                except Exception:
                    log.warning("Could not refresh the waiting evaluations' heartbeat.")
        return self.stopping()

    def _fail_waiting(self, ids: list[str]) -> None:
        for evaluation_id in ids:
            try:
                with self.db.transaction() as session:
                    repo.fail_queued(session, evaluation_id, error=_DRAINED, now=utcnow())
            except Exception:
                log.warning("Could not mark evaluation %s failed.", evaluation_id)
