"""The audit log of admin actions: who did what, to what, when.

The use cases record their own entries (``record``) in the transaction that does the action, so
an action and its entry are stored together or not at all, whoever calls the use case: the HTTP
API, the command line or the admin console.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import audit as repo
from app.db.repositories.audit import AuditRow
from app.db.types import utcnow
from app.errors import Forbidden, ValidationFailed
from app.schemas.audit import AuditActor, AuditEntryOut, AuditList
from app.schemas.common import position_of

from .context import Principal

__all__ = ["ABOUT_A_USER", "ACTIONS", "CLI", "entry_out", "list_audit", "record"]

ACTIONS = (
    "user.delete",
    "user.learner",
    "user.prior",
    "user.export",
    "user.import",
    "model.reset",
    "model.export",
    "model.import",
    "model.rebuild",
    "key.create",
    "key.revoke",
    "mission.set",
    "correction.add",
    "correction.lift",
    "fleet.prior",
    "fleet.history",
    "fleet.retention",
    "evaluation.start",
    "evaluation.cancel",
    "evaluation.run",
    "rollout.start",
    "rollout.share",
    "rollout.promote",
    "rollout.rollback",
    "shadow.start",
    "shadow.share",
    "shadow.stop",
)
# The actions whose target is a user: their entries' details are blanked when the user is erased.
ABOUT_A_USER = ("user.", "model.", "correction.")
CLI = Principal("cli", "admin", "default")  # an operator at the machine (``attune keys ...``)


def record(
    session: Session,
    actor: Principal,
    action: str,
    *,
    target: str,
    fleet: str | None,
    detail: dict[str, Any] | None = None,
) -> None:
    """Add the entry of an admin action to the current transaction."""
    if action not in ACTIONS:
        raise ValueError(f"unknown audit action {action!r}")
    repo.add(
        session,
        AuditRow(
            id=None,
            at=utcnow(),
            actor_key_id=actor.key_id,
            actor_role=actor.role,
            actor_fleet=actor.fleet,
            action=action,
            target=target,
            fleet=fleet,
            detail=detail,
        ),
    )


def entry_out(entry: AuditRow) -> AuditEntryOut:
    return AuditEntryOut(
        id=str(entry.id),
        at=entry.at,
        actor=AuditActor(key_id=entry.actor_key_id, role=entry.actor_role, fleet=entry.actor_fleet),
        action=entry.action,
        target=entry.target,
        fleet=entry.fleet,
        detail=entry.detail,
    )


def list_audit(
    session: Session, principal: Principal, *, limit: int, cursor: str | None
) -> AuditList:
    """Admin actions, newest first, a page at a time: of every fleet for an admin, of its own
    fleet for its staff."""
    if not principal.manages:
        raise Forbidden("This needs a staff or admin key.")
    before: int | None = None
    if cursor is not None:
        before = position_of(cursor)
        if before is None:
            raise ValidationFailed("cursor is not one this API returned.")
    rows = repo.list_page(
        session,
        before_id=before,
        limit=limit + 1,
        fleet=None if principal.is_admin else principal.fleet,
    )
    more = len(rows) > limit
    return AuditList(
        items=[entry_out(e) for e in rows[:limit]],
        next_cursor=str(rows[limit - 1].id) if more else None,
    )
