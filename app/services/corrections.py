"""Staff corrections of what was learned about a person: made, listed, lifted.

A correction is part of the user's history: it is stored (``corrections``), journalled (a
"correction" entry when made, a "lift" entry when lifted, each one model version), audited,
and taught to the learner, which keeps the rules in force in its state
(:mod:`app.learning.guidance`). ``attune models rebuild`` replays them in order with the rest.
"""

from __future__ import annotations

import datetime as dt
from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import corrections as repo
from app.db.repositories import episodes as episodes_repo
from app.db.repositories import retention as retention_repo
from app.db.repositories.corrections import CorrectionRow
from app.db.repositories.users import UserRow
from app.db.types import utcnow
from app.errors import Conflict, NotFound, ValidationFailed
from app.learning.guidance import Guidance, Reason, Rule
from app.learning.learners import TabularLearner
from app.schemas.profile import CorrectionIn, CorrectionList, CorrectionOut

from . import audit
from .auth import require_manager
from .context import Principal, ServiceContext, body_hash
from .folds import History
from .person_model import PersonModel, rule_of
from .users import visible_user

__all__ = [
    "CorrectionRefused",
    "add_correction",
    "correction_views",
    "lift_correction",
    "list_corrections",
    "rule_of",
]


class CorrectionRefused(ValidationFailed):
    """A correction that does not fit the user's mission (422): ``reasons``, the learning
    core's, for the caller's own words; the detail is the first reason's sentence."""

    def __init__(self, reasons: tuple[Reason, ...]) -> None:
        super().__init__(reasons[0].sentence())
        self.reasons = reasons


def add_correction(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    body: CorrectionIn,
    *,
    fleet: str | None = None,
    user: UserRow | None = None,
) -> tuple[CorrectionOut, bool]:
    """Put a correction in force (staff of the fleet, admin); idempotent on
    ``correction_id``: (the correction, True) when made, (it, False) for a repeat. The one
    check of what it names is the learning core's rule (:class:`CorrectionRefused` with its
    reasons). ``user``: the row, locked, when the caller already holds it."""
    require_manager(principal)
    if user is None:
        user = visible_user(session, principal, user_id, fleet=fleet, lock=True)
    digest = body_hash(body)
    earlier = repo.by_id(session, user.id, body.correction_id)
    if earlier is not None:
        if earlier.request_hash != digest:
            raise Conflict(
                f"correction_id {body.correction_id!r} was already used with another body."
            )
        learner = PersonModel.open(session, ctx, user).learner
        return _out(session, user, earlier, learner.guidance, learner), False
    model = PersonModel.open(session, ctx, user, write=True)
    learner = model.learner
    now = utcnow()
    row = CorrectionRow(
        id=None,
        user_pk=user.id,
        correction_id=body.correction_id,
        kind=body.kind,
        time_slot=body.time_slot,
        situation=body.situation,
        service=body.service,
        detail=body.detail,
        note=body.note,
        actor_key_id=principal.key_id,
        created_at=now,
        model_version=model.version + 1,
        lifted_at=None,
        lifted_by=None,
        request_hash=digest,
        response={},
    )
    rule = rule_of(row, learner.episodes)
    reasons = rule.reasons(learner.mission)
    if reasons:
        raise CorrectionRefused(reasons)
    made = CorrectionOut(
        correction_id=row.correction_id,
        kind=body.kind,
        time_slot=row.time_slot,
        situation=row.situation,
        service=row.service,
        detail=row.detail,
        note=row.note,
        author=row.actor_key_id,
        created_at=now,
        status="in_force",
        model_version=row.model_version,
    )
    row.response = made.model_dump(mode="json")
    row_id = repo.add(session, row)
    model.correct(
        rule, row_id, context=learner.mission.context_index(body.time_slot, body.situation)
    )
    model.save()
    audit.record(
        session,
        principal,
        "correction.add",
        target=user_id,
        fleet=user.fleet,
        detail={
            "correction_id": body.correction_id,
            "kind": body.kind,
            "time_slot": body.time_slot,
            "situation": body.situation,
            "service": body.service,
            "detail": body.detail,
            "version": model.version,
        },
    )
    return _out(session, user, row, learner.guidance, learner), True


def lift_correction(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    correction_id: str,
    *,
    fleet: str | None = None,
) -> CorrectionOut:
    """Lift a correction (staff of the fleet, admin); lifting a lifted one changes nothing."""
    require_manager(principal)
    user = visible_user(session, principal, user_id, fleet=fleet, lock=True)
    row = repo.by_id(session, user.id, correction_id)
    if row is None or row.id is None:
        raise NotFound(f"No correction {correction_id!r} for user {user_id!r}.")
    if row.lifted_at is not None:
        learner = PersonModel.open(session, ctx, user).learner
        return _out(session, user, row, learner.guidance, learner)
    model = PersonModel.open(session, ctx, user, write=True)
    model.lift(
        rule_of(row, model.learner.episodes), row.id, context=_context_or_zero(model.learner, row)
    )
    model.save()
    learner = model.learner
    row.lifted_at, row.lifted_by = utcnow(), principal.key_id
    repo.lift(session, row.id, at=row.lifted_at, by=principal.key_id)
    audit.record(
        session,
        principal,
        "correction.lift",
        target=user_id,
        fleet=user.fleet,
        detail={"correction_id": correction_id, "version": model.version},
    )
    return _out(session, user, row, learner.guidance, learner)


def _context_or_zero(learner: TabularLearner[Any], row: CorrectionRow) -> int:
    try:
        return learner.mission.context_index(row.time_slot, row.situation)
    except ValueError:  # the fleet's mission no longer has the context
        return 0


def list_corrections(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    *,
    fleet: str | None = None,
) -> CorrectionList:
    """Every correction of the user, lifted ones too, oldest first (staff, admin, robots of the
    fleet may read them)."""
    user = visible_user(session, principal, user_id, fleet=fleet)
    learner = PersonModel.open(session, ctx, user).learner
    return CorrectionList(items=correction_views(session, user, learner))


def correction_views(
    session: Session, user: UserRow, learner: TabularLearner[Any], *, lifted: bool = True
) -> list[CorrectionOut]:
    """The user's corrections with their status in ``learner``; rules the model holds without
    a stored row (imported from another user's export) are listed too."""
    rows = repo.for_user(session, user.id)
    out = [_out(session, user, row, learner.guidance, learner) for row in rows]
    stored = {row.correction_id for row in rows}
    for rule in learner.guidance.rules:
        if rule.id not in stored:
            out.append(_from_rule(session, user, rule, learner))
    return [c for c in out if lifted or c.status != "lifted"]


def _out(
    session: Session,
    user: UserRow,
    row: CorrectionRow,
    guidance: Guidance,
    learner: TabularLearner[Any],
) -> CorrectionOut:
    rule = guidance.get(row.correction_id)
    status, overridden_at = _status(session, user, rule, learner)
    if row.lifted_at is not None:
        status = "lifted"
    names = rule if rule is not None else row  # a mission change may have renamed them
    return CorrectionOut(
        correction_id=row.correction_id,
        kind=row.kind,  # type: ignore[arg-type]
        time_slot=names.time_slot,
        situation=names.situation,
        service=names.service,
        detail=names.detail,
        note=row.note,
        author=row.actor_key_id,
        created_at=row.created_at,
        status=status,
        overridden_at=overridden_at,
        lifted_at=row.lifted_at,
        lifted_by=row.lifted_by,
        model_version=row.model_version,
    )


def _from_rule(
    session: Session, user: UserRow, rule: Any, learner: TabularLearner[Any]
) -> CorrectionOut:
    status, overridden_at = _status(session, user, rule, learner)
    meta = rule.meta
    try:
        created = dt.datetime.fromisoformat(str(meta.get("at")))
    except ValueError:
        created = utcnow()
    return CorrectionOut(
        correction_id=rule.id,
        kind=rule.kind.value,
        time_slot=rule.time_slot,
        situation=rule.situation,
        service=rule.service,
        detail=rule.detail,
        note=meta.get("note"),
        author=str(meta.get("author") or "imported"),
        created_at=created,
        status=status,
        overridden_at=overridden_at,
        model_version=0,
    )


def _status(
    session: Session, user: UserRow, rule: Rule | None, learner: TabularLearner[Any]
) -> tuple[Any, dt.datetime | None]:
    if rule is None:
        return "lifted", None
    if rule.reasons(learner.mission):  # checked once per mission: the rule keeps the answer
        return "idle", None
    if rule.overridden_at is None:
        return "in_force", None
    at = episodes_repo.occurred_at_of(session, user.id, rule.overridden_at)
    if at is None:  # removed by a retention run: its fold keeps the moment
        moment = History.from_doc(retention_repo.doc(session, user.id)).moments.get(
            rule.overridden_at
        )
        at = None if moment is None else moment.at
    return "overridden", at
