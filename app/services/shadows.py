"""Shadows: a candidate learner that decides beside a fleet's learners without acting
(``/v1/admin/fleets/{fleet}/shadow``; docs/api.md "Shadows").

For the share of the fleet's people whose salted hash falls below the shadow's ``share``, every
decision the robots were told is also decided by the candidate: once the episode has ended, the
service's shadow pass (every ``ATTUNE_SHADOW_SECONDS``, one worker of the deployment at a time,
by a lease, in a Python process of its own: :func:`pass_in_process`) replays the person's
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

import datetime as dt
import json
import logging
import os
import secrets
import subprocess
import sys
from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import shadows as repo
from app.db.repositories import users as users_repo
from app.db.repositories.shadows import ShadowRow
from app.db.session import Database
from app.db.types import utcnow
from app.errors import Conflict, Forbidden, NotFound, ValidationFailed
from app.logs import FIELDS
from app.settings import Settings

from . import audit
from .auth import require_manager
from .context import Principal, ServiceContext
from .evaluation import CandidateSpec, candidate_spec, evaluate_fleet, shadow_decisions
from .rollouts import hash_place

__all__ = [
    "LEASE",
    "pass_in_process",
    "put_shadow",
    "shadow_pass",
    "shadow_view",
    "stop_shadow",
]

log = logging.getLogger("attune.shadows")

LEASE = "shadows"
"""The lease of the shadows' pass (:class:`app.services.periodic.Periodic`)."""
PASS_PEOPLE = 200
"""The most people one pass replays per shadow; the others wait for the next pass."""
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
    try:
        spec = candidate_spec(algorithm, params)
    except ValueError as exc:
        raise ValidationFailed(
            f"candidate: {exc}", fields=[{"loc": ["body", "candidate"], "msg": str(exc)}]
        ) from None
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
) -> dict[str, int]:
    """One pass over every running shadow: the candidate decides at the decisions of the
    episodes closed since the last pass, and its off-policy estimate is made again when it is
    older than ``ATTUNE_SHADOW_ESTIMATE_MINUTES``. The decisions stored, by fleet."""
    now = now or utcnow()
    upto = now - SETTLE
    with db.transaction(write=False) as session:
        shadows = repo.running(session)
    added: dict[str, int] = {}
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
        for user in people[:max_people]:
            with db.transaction(write=False) as session:
                done = repo.done_for(session, row.id, user.id)
                found = shadow_decisions(session, ctx, user, spec, since=row.started_at, done=done)
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
            with db.transaction() as session:
                repo.add_decisions(session, rows)
            n += len(rows)
        if len(people) <= max_people:
            with db.transaction() as session:
                repo.checked(session, row.id, upto)
        added[row.fleet] = n
        stale = row.estimated_at is None or now - row.estimated_at >= dt.timedelta(
            minutes=ctx.settings.shadow_estimate_minutes
        )
        if estimate and stale:
            _estimate(db, ctx, row, spec, now)
        if n:
            log.info(
                "Shadow %s of fleet %s: %d decisions of %d people.",
                row.id,
                row.fleet,
                n,
                min(len(people), max_people),
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

PASS_TIMEOUT_S = 15 * 60
"""A pass in a process of its own that runs longer than this is stopped (the next one goes on
from where it stopped: what it stored stays, and the episodes it did not reach are looked at
again)."""
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
    "shadow_estimate_minutes",
    "evaluation_max_minutes",
    "log_level",
    "log_format",
)


def pass_in_process(settings: Settings, *, timeout: float = PASS_TIMEOUT_S) -> int:
    """One :func:`shadow_pass` in a Python process of its own, with the service's database and
    settings (given on its standard input, the key with them, never on its command line): the
    replays do not share the worker's interpreter with the robots' requests, and the process
    runs at a lower priority (``nice`` 10), so that a busy machine serves the robots first. Its
    log lines go to the worker's standard error. The process's exit status (0: done)."""
    given: dict[str, Any] = {name: getattr(settings, name) for name in _PASSED}
    given["mission_path"] = None if settings.mission_path is None else str(settings.mission_path)
    key = settings.database_key
    if key is not None:
        given["db_key"] = key.get_secret_value()
    try:
        done = subprocess.run(
            [sys.executable, "-m", "app.services.shadows"],
            input=json.dumps(given).encode(),
            timeout=timeout,
            check=False,
        )
    except subprocess.TimeoutExpired:
        log.warning("The shadows' pass ran longer than %.0f s and was stopped.", timeout)
        return -1
    if done.returncode != 0:
        log.warning("The shadows' pass ended with status %d.", done.returncode)
    return done.returncode


def _main() -> int:
    """The pass's process: settings as JSON on standard input."""
    import logging.config

    from app.logs import logging_config

    given = json.loads(sys.stdin.buffer.read() or b"{}")
    if hasattr(os, "nice"):
        os.nice(10)  # the robots' requests first, when the machine is busy
    settings = Settings(_env_file=None, **given)  # type: ignore[call-arg]
    logging.config.dictConfig(logging_config(settings.log_level, settings.log_format))
    db = Database(settings)
    try:
        shadow_pass(db, ServiceContext.from_settings(settings))
    finally:
        db.dispose()
    return 0


if __name__ == "__main__":
    sys.exit(_main())
