"""Shadows: a candidate learner that decides beside a fleet's learners without acting
(``/v1/admin/fleets/{fleet}/shadow``; docs/api.md "Shadows").

For the share of the fleet's people whose salted hash falls below the shadow's ``share``, every
decision the robots were told is also decided by the candidate: once the episode has ended, the
service's shadow pass (every ``ATTUNE_SHADOW_SECONDS``, one worker of the deployment at a time,
by a lease, in a Python process of its own: :class:`PassProcess`) replays the person's
history into the candidate as the evaluation does (so that at each decision it knows what the
robot's learner knew then), asks it at the decision's state, draws its action from its
distribution, and stores both with the candidate's probability of the robot's action
(``shadow_decisions``). Nothing of this runs in a robot's request: the robots' latency pays only
for the pass's share of the machine's CPU (measured by ``bench/shadow.py``).

A look (``GET .../shadow``) says how often the candidate would have done what the robot did,
and the newest off-policy estimate of what it would have earned with the fleet's people over the
episodes since the shadow started (:func:`app.services.evaluation.evaluate_fleet`, made again
every ``ATTUNE_SHADOW_ESTIMATE_MINUTES`` by the pass).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import functools
import json
import logging
import os
import secrets
import subprocess
import sys
import threading
from collections.abc import Callable
from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import leases as leases_repo
from app.db.repositories import shadows as repo
from app.db.repositories import users as users_repo
from app.db.repositories.shadows import ShadowRow
from app.db.session import Database
from app.db.types import utcnow
from app.errors import Conflict, Forbidden, NotFound, ValidationFailed
from app.logs import FIELDS
from app.settings import Settings

from . import audit, leases
from .auth import require_manager
from .context import Principal, ServiceContext
from .evaluation import (
    CandidateSpec,
    ReplayCache,
    candidate_spec,
    evaluate_fleet,
    live_candidate,
    shadow_decisions,
)
from .rollouts import hash_place

__all__ = [
    "LEASE",
    "PassProcess",
    "pass_in_process",
    "put_shadow",
    "shadow_pass",
    "shadow_view",
    "stop_shadow",
]

log = logging.getLogger("attune.shadows")

LEASE = "shadows"
"""The lease of the shadows' pass: held by the pass process (:class:`PassProcess`)."""
PASS_PEOPLE = 200
"""The most people one pass replays per shadow; the others wait for the next pass."""
WRITE_ROWS = 100
"""A pass stores its decisions this many at a time, each batch in a short write transaction."""
SETTLE = dt.timedelta(seconds=2)
"""Episodes closed less than this before a pass are left to the next one (a transaction that
closed one may not have committed yet)."""


def _spec_of(row: ShadowRow) -> CandidateSpec:
    return candidate_spec(row.algorithm, row.params)


def _check_fleet(principal: Principal, fleet: str) -> None:
    require_manager(principal)
    if not principal.sees(fleet):
        raise Forbidden("Staff keys shadow learners in their own fleet only.")


def _percent(part: int, whole: int) -> str:
    return f"{100.0 * part / whole:.0f}%" if whole else "-"


def _view(session: Session, row: ShadowRow) -> dict[str, Any]:
    spec = _spec_of(row)
    decisions, agreeing, expected, people = repo.agreement(session, row.id)
    if decisions:
        summary = (
            f"{spec.label} would have done what the robots did in {_percent(agreeing, decisions)} "
            f"of {decisions:,} decisions with {people} "
            f"{'person' if people == 1 else 'people'}."
        )
    else:
        summary = f"{spec.label} has not decided yet: it decides once an episode has ended."
    estimate = row.estimate
    agreement = summary
    estimated: str | None = None
    if estimate is not None:
        (candidate,) = estimate["candidates"]
        said = candidate["verdict"]
        if candidate.get("reason"):  # "not enough evidence: ...": whose, said
            said = f"Its estimate: {said}"
        estimated = f"{said[:1].upper()}{said[1:]}."
        summary += f" {estimated}"
    return {
        "shadow_id": row.id,
        "fleet": row.fleet,
        "candidate": spec.to_dict(),
        "share": row.share,
        "status": row.status,
        "started_at": row.started_at,
        "started_by": row.started_by,
        "stopped_at": row.stopped_at,
        "stopped_by": row.stopped_by,
        "checked_until": row.checked_until,
        "decisions": decisions,
        "agreeing": agreeing,
        "agreement": agreeing / decisions if decisions else None,
        "expected_agreement": expected if decisions else None,
        "people": people,
        "estimate": estimate,
        "estimated_at": row.estimated_at,
        "summary": summary,
        "agreement_summary": agreement,
        "estimate_summary": estimated,
    }


def shadow_view(
    session: Session, ctx: ServiceContext, principal: Principal, fleet: str
) -> dict[str, Any]:
    """``GET .../shadow``: the fleet's newest shadow, how often its candidate agreed, and its
    off-policy estimate; 404 when the fleet never had one."""
    _check_fleet(principal, fleet)
    row = repo.latest(session, fleet)
    if row is None:
        raise NotFound(f"Fleet {fleet!r} has had no shadow.")
    return _view(session, row)


def put_shadow(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    fleet: str,
    *,
    algorithm: str,
    params: dict[str, Any],
    share: float,
) -> tuple[dict[str, Any], bool]:
    """Start a shadow of the candidate over ``share`` of the fleet's people, or change the share
    of the one running (the same candidate): (the view, started)."""
    _check_fleet(principal, fleet)
    spec = live_candidate(algorithm, params)
    if not 0.0 < share <= 1.0:
        raise ValidationFailed(
            "share must be above 0 and at most 1.",
            fields=[{"loc": ["body", "share"], "msg": "out of range"}],
        )
    now = utcnow()
    running = repo.running_of(session, fleet)
    if running is not None:
        if _spec_of(running).key != spec.key:
            raise Conflict(
                f"A shadow of {_spec_of(running).label} is running in fleet {fleet!r}: stop it "
                "before shadowing another learner."
            )
        if share != running.share:
            repo.set_share(session, running.id, share)
            audit.record(
                session,
                principal,
                "shadow.share",
                target=fleet,
                fleet=fleet,
                detail={"shadow": running.id, "share": share, "was": running.share},
            )
        return _view(session, repo.running_of(session, fleet) or running), False
    row = ShadowRow(
        id=f"sh_{secrets.token_hex(16)}",
        fleet=fleet,
        algorithm=spec.algorithm,
        params=dict(spec.params),
        share=share,
        salt=secrets.token_hex(8),
        status="running",
        started_at=now,
        started_by=principal.key_id,
        stopped_at=None,
        stopped_by=None,
        checked_until=now,
        estimate=None,
        estimated_at=None,
    )
    repo.add(session, row)
    audit.record(
        session,
        principal,
        "shadow.start",
        target=fleet,
        fleet=fleet,
        detail={"shadow": row.id, "candidate": spec.key, "share": share},
    )
    return _view(session, row), True


def stop_shadow(
    session: Session, ctx: ServiceContext, principal: Principal, fleet: str
) -> dict[str, Any]:
    """Stop the fleet's running shadow (its decisions stay); 409 when none runs."""
    _check_fleet(principal, fleet)
    running = repo.running_of(session, fleet)
    if running is None:
        raise Conflict(f"No shadow is running in fleet {fleet!r}.")
    repo.stop(session, running.id, by=principal.key_id, now=utcnow())
    audit.record(
        session, principal, "shadow.stop", target=fleet, fleet=fleet, detail={"shadow": running.id}
    )
    return _view(session, repo.latest(session, fleet) or running)


# ---------------------------------------------------------------------------------------------
# The pass


def shadow_pass(
    db: Database,
    ctx: ServiceContext,
    *,
    now: dt.datetime | None = None,
    max_people: int = PASS_PEOPLE,
    estimate: bool = True,
    cache: ReplayCache | None = None,
    stopping: Callable[[], bool] = lambda: False,
) -> dict[str, int]:
    """One pass over every running shadow: the candidate decides at the decisions of the
    episodes closed since the last pass, and its off-policy estimate is made again when it is
    older than ``ATTUNE_SHADOW_ESTIMATE_MINUTES``. The decisions stored, by fleet.

    ``cache`` (the pass process's, kept between its passes) holds each person's candidate as
    the last pass left it, so that a pass teaches it only what is new. ``stopping()`` true ends
    the pass after the person in hand (the episodes it did not reach are looked at again)."""
    now = now or utcnow()
    upto = now - SETTLE
    with db.transaction(write=False) as session:
        shadows = repo.running(session)
    added: dict[str, int] = {}
    if cache is not None:  # the candidates of shadows that stopped
        live = {row.id for row in shadows}
        cache.drop(lambda key: key[0] not in live)
    for row in shadows:
        spec = _spec_of(row)
        with db.transaction(write=False) as session:
            people = []
            for user_pk in repo.people_with_closed(
                session, row.fleet, after=row.checked_until, upto=upto
            ):
                user = users_repo.by_pk(session, user_pk)
                if user is not None and hash_place(row.salt, user.user_id) < row.share:
                    people.append(user)
        n = 0
        reached = 0
        found_rows: list[dict[str, Any]] = []  # stored at the end of the shadow's pass, at once
        for user in people[:max_people]:
            if stopping():
                break
            reached += 1
            with db.transaction(write=False) as session:
                found = shadow_decisions(
                    session,
                    ctx,
                    user,
                    spec,
                    since=row.started_at,
                    done=functools.partial(repo.done_among, session, row.id),
                    cache=cache,
                    key=(row.id, user.id),
                )
            rows = [
                {
                    "decision_id": d.decision_id,
                    "shadow_id": row.id,
                    "user_pk": user.id,
                    "decided_at": d.decided_at,
                    "state": d.state,
                    "action": d.action,
                    "probabilities": d.probabilities,
                    "logged_action": d.logged_action,
                    "logged_probability": d.logged_probability,
                    "agrees": d.agrees,
                }
                for d in found
            ]
            found_rows.extend(rows)
            n += len(rows)
            if len(found_rows) >= WRITE_ROWS:
                with db.transaction() as session:
                    repo.add_decisions(session, found_rows)
                found_rows = []
        # A few write transactions a pass, each short (on SQLite the robots' writes wait for
        # one); had one failed, the next pass decides those again (its candidates, taught past
        # those decisions, start again from the base).
        with db.transaction() as session:
            repo.add_decisions(session, found_rows)
            if reached == len(people):  # every person with a closed episode: checked up to here
                repo.checked(session, row.id, upto)
        added[row.fleet] = n
        stale = row.estimated_at is None or now - row.estimated_at >= dt.timedelta(
            minutes=ctx.settings.shadow_estimate_minutes
        )
        if estimate and stale and not stopping():
            _estimate(db, ctx, row, spec, now)
        if n:
            log.info(
                "Shadow %s of fleet %s: %d decisions of %d people.",
                row.id,
                row.fleet,
                n,
                reached,
                extra={FIELDS: {"shadow": row.id, "fleet": row.fleet, "decisions": n}},
            )
    return added


def _estimate(
    db: Database, ctx: ServiceContext, row: ShadowRow, spec: CandidateSpec, now: dt.datetime
) -> None:
    """The candidate's off-policy estimate over the fleet's episodes since the shadow started,
    stored with the shadow (without its per-person rows)."""
    try:
        found = evaluate_fleet(db, ctx, row.fleet, [spec], since=row.started_at)
    except NotFound:
        return
    result = {k: v for k, v in found.to_dict().items() if k != "persons"}
    with db.transaction() as session:
        repo.set_estimate(session, row.id, result, at=now)


# ---------------------------------------------------------------------------------------------
# The pass in a process of its own

# What the pass's process needs of the service's settings; the rest keep their defaults.
_PASSED = (
    "database_url",
    "database_pooler",
    "sqlite_busy_timeout_s",
    "db_pool_size",
    "seed",
    "mission_path",
    "model_cache_size",
    "snapshot_every",
    "shadow_seconds",
    "shadow_estimate_minutes",
    "evaluation_max_minutes",
    "log_level",
    "log_format",
)
START_LEASE = dt.timedelta(minutes=1)
"""How long the lease a worker takes for the pass process it starts lasts, until that process
renews it (a process that dies as it starts holds the shadows' work back no longer)."""
STOP_WAIT_S = 10.0
"""How long a worker that stops waits for its pass process to end before it stops it."""


def _given(settings: Settings, *, holder: str | None = None) -> bytes:
    """The settings the pass's process needs, as one line of JSON (the database key with them:
    on its standard input, never on its command line), and the name under which its worker
    took the shadows' lease for it (``holder``; None: the process takes it)."""
    given: dict[str, Any] = {name: getattr(settings, name) for name in _PASSED}
    given["lease_holder"] = holder
    given["mission_path"] = None if settings.mission_path is None else str(settings.mission_path)
    key = settings.database_key
    if key is not None:
        given["db_key"] = key.get_secret_value()
    return json.dumps(given).encode() + b"\n"


def work_waiting(db: Database, *, now: dt.datetime | None = None) -> bool:
    """Whether a pass process should start: a shadow runs, and no process of the deployment
    holds the shadows' lease. Two small reads: what a worker pays every
    ``ATTUNE_SHADOW_SECONDS`` when no shadow runs."""
    now = now or utcnow()
    with db.transaction(write=False) as session:
        if not repo.running(session):
            return False
        current = leases_repo.get(session, LEASE)
    return current is None or _utc(current.expires_at) <= now


def _utc(at: dt.datetime) -> dt.datetime:
    return at if at.tzinfo is not None else at.replace(tzinfo=dt.UTC)


def pass_in_process(settings: Settings, *, timeout: float = 15 * 60) -> int:
    """The pass's process (:func:`_main`) run to its end: it passes until no shadow runs (or
    at once when another process holds the lease). Its exit status (0: done)."""
    try:
        done = subprocess.run(
            [sys.executable, "-m", "app.services.shadows"],
            input=_given(settings),
            timeout=timeout,
            check=False,
        )
    except subprocess.TimeoutExpired:
        log.warning("The shadows' pass process ran longer than %.0f s and was stopped.", timeout)
        return -1
    return done.returncode


class PassProcess:
    """This worker's side of the shadows' pass: every ``ATTUNE_SHADOW_SECONDS`` a thread
    (``attune-shadows``) looks whether a shadow runs and nobody holds the shadows' lease
    (:func:`work_waiting`); if so, it starts the pass's process, ``python -m
    app.services.shadows`` (:func:`_main`), with the settings on its standard input, and leaves
    it be while it runs. That process takes the lease, runs a pass every
    ``ATTUNE_SHADOW_SECONDS`` while a shadow runs, and ends when none does, when it loses the
    lease, or when its standard input closes (this worker stopped, or died).

    A process of its own, at a lower priority (``nice`` 10), so that the replays do not share
    a worker's interpreter with the robots' requests and a busy machine serves the robots
    first; long-lived, so that Python's start (a second and more of CPU) is paid once per
    shadow, not once per pass, and what it replayed stays learned between passes (its
    :class:`ReplayCache`). Without a shadow nothing starts."""

    def __init__(
        self, db: Database, settings: Settings, *, stopping: Callable[[], bool] = lambda: False
    ) -> None:
        self.db, self.settings, self.stopping = db, settings, stopping
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._process: subprocess.Popen[bytes] | None = None
        self._lock = threading.Lock()

    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop, name="attune-shadows", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.wait(self.settings.shadow_seconds):
            if self.stopping():
                self._end()
                return
            try:
                self.tick()
            except Exception:
                log.exception(
                    "Could not look for the shadows' work; looking again in %.0f s.",
                    self.settings.shadow_seconds,
                )

    def running(self) -> bool:
        """Whether this worker's pass process runs."""
        with self._lock:
            return self._process is not None and self._process.poll() is None

    def tick(self) -> bool:
        """Start the pass's process if it should run and does not (True when it started)."""
        with self._lock:
            process = self._process
            if process is not None:
                status = process.poll()
                if status is None:
                    return False
                if status != 0:
                    log.warning("The shadows' pass process ended with status %d.", status)
                if process.stdin is not None:
                    with contextlib.suppress(OSError):
                        process.stdin.close()
                self._process = None
            if self._stop.is_set() or not work_waiting(self.db):
                return False
            # Taken here, before the process starts (a second or more to import), so that
            # no other worker starts one meanwhile; the process renews it under this name.
            try:
                lease = leases.take(self.db, LEASE, now=utcnow(), ttl=START_LEASE)
            except leases.LeaseHeld:
                return False
            try:
                process = subprocess.Popen(
                    [sys.executable, "-m", "app.services.shadows"], stdin=subprocess.PIPE
                )
                assert process.stdin is not None
                process.stdin.write(_given(self.settings, holder=lease.holder))
                process.stdin.flush()  # kept open: its end tells the process to stop
            except Exception:
                lease.release(utcnow())
                raise
            self._process = process
            return True

    def _end(self, timeout: float = STOP_WAIT_S) -> None:
        with self._lock:
            process, self._process = self._process, None
        if process is None:
            return
        if process.stdin is not None:
            with contextlib.suppress(OSError):
                process.stdin.close()
        try:
            process.wait(timeout)
        except subprocess.TimeoutExpired:
            log.warning("The shadows' pass process did not end in %.0f s; stopping it.", timeout)
            process.terminate()
            try:
                process.wait(timeout)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()

    def stop(self, timeout: float = STOP_WAIT_S) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self._end(timeout)


def _main() -> int:
    """The pass's process: its settings as a line of JSON on standard input, which stays open
    until the worker stops (see :class:`PassProcess`)."""
    import logging.config

    from app.logs import logging_config

    given = json.loads(sys.stdin.buffer.readline() or b"{}")
    holder = given.pop("lease_holder", None)
    closed = threading.Event()

    def watch() -> None:  # the worker closed the pipe, or died
        with contextlib.suppress(OSError, ValueError):
            while sys.stdin.buffer.read(4096):
                pass
        closed.set()

    threading.Thread(target=watch, name="attune-shadows-stdin", daemon=True).start()
    if hasattr(os, "nice"):
        os.nice(10)  # the robots' requests first, when the machine is busy
    settings = Settings(_env_file=None, **given)  # type: ignore[call-arg]
    logging.config.dictConfig(logging_config(settings.log_level, settings.log_format))
    db = Database(settings)
    ctx = ServiceContext.from_settings(settings)
    cache = ReplayCache()
    try:
        with leases.held(db, LEASE, holder=holder) as lease:
            while True:  # a first pass even when the pipe is closed already (pass_in_process)
                lease.check()
                with db.transaction(write=False) as session:
                    if not repo.running(session):
                        break
                try:
                    shadow_pass(db, ctx, cache=cache)
                except Exception:
                    log.exception(
                        "The shadows' pass failed; it runs again in %.0f s.",
                        settings.shadow_seconds,
                    )
                if closed.wait(max(settings.shadow_seconds, 0.5)):
                    break
    except leases.LeaseHeld:
        pass  # another process passes
    except leases.LeaseLost as exc:
        log.warning("The shadows' pass stopped: %s", exc)
    finally:
        db.dispose()
    return 0


if __name__ == "__main__":
    sys.exit(_main())
