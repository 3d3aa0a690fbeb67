"""Users: create or update, read, list, delete; and who may see whom.

A user is (fleet, user id): each fleet has its own ids. A request about a user means the
caller's own fleet; an admin may name another with ``fleet``. A fleet the caller may not see is
answered exactly as a user that does not exist (404), so nothing can be learned about it.
"""

from __future__ import annotations

import base64
import binascii
import logging
import re
from dataclasses import dataclass
from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import audit as audit_repo
from app.db.repositories import evaluations as evaluations_repo
from app.db.repositories import users as repo
from app.db.repositories.users import UserRow
from app.db.types import utcnow
from app.errors import Conflict, Forbidden, NotFound, ValidationFailed
from app.learning.config import PARAMS
from app.learning.learners import TabularLearner
from app.schemas.common import CLIENT_ID_PATTERN
from app.schemas.users import LearnerSpec, UserIn, UserList, UserOut

from . import audit, rollouts
from .auth import ROLES, require_manager
from .context import Principal, ServiceContext
from .missions import current_version
from .person_model import PersonModel, fresh_learner
from .prior import starting_learner

log = logging.getLogger("attune.users")

__all__ = [
    "USER_FIELD_RIGHTS",
    "FieldRight",
    "create_user",
    "delete_user",
    "fleet_of",
    "get_user",
    "list_users",
    "no_user",
    "put_user",
    "user_out",
    "visible_user",
]


def no_user(user_id: str) -> NotFound:
    return NotFound(f"No user {user_id!r} in your fleet.")


def fleet_of(principal: Principal, fleet: str | None, user_id: str) -> str:
    """The fleet a request about ``user_id`` means: the caller's own, or the one an admin
    names. Another fleet named by anyone else is answered as a missing user."""
    if fleet is None or fleet == principal.fleet:
        return principal.fleet
    if principal.is_admin:
        return fleet
    raise no_user(user_id)


def visible_user(
    session: Session,
    principal: Principal,
    user_id: str,
    *,
    fleet: str | None = None,
    lock: bool = False,
) -> UserRow:
    """The user ``user_id`` of the fleet the request means (locked for the transaction with
    ``lock``), or 404."""
    in_fleet = fleet_of(principal, fleet, user_id)
    user = repo.lock(session, in_fleet, user_id) if lock else repo.get(session, in_fleet, user_id)
    if user is None:
        raise no_user(user_id)
    return user


def user_out(user: UserRow) -> UserOut:
    return UserOut(
        user_id=user.user_id,
        fleet=user.fleet,
        display_name=user.display_name,
        learner=LearnerSpec(algorithm=user.algorithm, params=dict(user.params)),
        created_at=user.created_at,
        episodes=user.episode_count,
        fleet_prior=user.fleet_prior,
    )


def create_user(
    session: Session,
    ctx: ServiceContext,
    fleet: str,
    user_id: str,
    *,
    spec: LearnerSpec | None = None,
    display_name: str | None = None,
    fleet_prior: bool | None = None,
) -> bool:
    """Create the user in ``fleet`` unless the fleet has that id; True when created. (Two
    requests creating the same user at once: one creates it, both go on.) The model starts from
    the fleet's prior when it is in force for the user (``app.services.prior``), else fresh."""
    default = spec is None
    spec = spec or LearnerSpec()
    # A fleet's rollout gives a newcomer whose learner nobody chose an arm (and, in the
    # candidate's arm or once it was promoted, the candidate as their learner).
    arm = rollouts.arm_for_newcomer(session, fleet, user_id) if default else None
    algorithm, params = spec.algorithm, spec.params
    if arm is not None and arm[2] is not None:
        algorithm, params = arm[2].algorithm, dict(arm[2].params)
    takes_part = fleet_prior is not False
    version = current_version(session, ctx, fleet, for_new_user=True)
    learner, origin = starting_learner(
        session, ctx, fleet, algorithm, params, version, takes_part=takes_part
    )
    state = learner.to_state()
    created = repo.create(
        session,
        user_id=user_id,
        fleet=fleet,
        algorithm=algorithm,
        params=learner.params.to_dict(),
        display_name=display_name,
        state=state,
        mission_version=version,
        now=utcnow(),
        fleet_prior=takes_part,
        base=(state, origin.contributors or 0) if origin.kind == "fleet_prior" else None,
    )
    if created and arm is not None and arm[1]:
        default_params = PARAMS[spec.algorithm].from_dict(dict(spec.params)).to_dict()
        rollouts.record_newcomer(session, arm[0], arm[1], user_id, (spec.algorithm, default_params))
    return created


@dataclass(frozen=True, slots=True)
class FieldRight:
    """The roles that may set a field of ``PUT /v1/users/{user_id}``: on the user the request
    creates (``creates``), and on a user that exists already (``changes``: to another value
    than the stored one; sending the stored value changes nothing and is anyone's)."""

    creates: frozenset[str]
    changes: frozenset[str]


EVERYONE = frozenset(ROLES)
MANAGERS = frozenset(("staff", "admin"))
# Who may set what on PUT /v1/users/{user_id}: every field of ``UserIn`` and every query
# parameter but ``fleet`` (which only says whose user is meant). What staff set, a robot key
# cannot undo: a robot may create a person with any of the body's fields (there is nothing yet
# to undo), and changes none of them afterwards; ``reset_model`` is staff's and admins' only.
# docs/api.md ("Who may set what") shows this table, and tests/api/test_fleet_matrix.py has a
# row per entry (it fails for a field without one). A field missing here is for staff and
# admins only.
USER_FIELD_RIGHTS: dict[str, FieldRight] = {
    "display_name": FieldRight(creates=EVERYONE, changes=MANAGERS),
    "learner": FieldRight(creates=EVERYONE, changes=MANAGERS),
    "fleet_prior": FieldRight(creates=EVERYONE, changes=MANAGERS),
    "reset_model": FieldRight(creates=MANAGERS, changes=MANAGERS),
}
_UNDECIDED = FieldRight(creates=MANAGERS, changes=MANAGERS)


def _check_rights(principal: Principal, names: list[str], *, creating: bool) -> None:
    """403 naming the fields ``principal`` may not set (on a new user with ``creating``)."""
    refused = []
    for name in names:
        right = USER_FIELD_RIGHTS.get(name, _UNDECIDED)
        if principal.role not in (right.creates if creating else right.changes):
            refused.append(name)
    if refused:
        what = " and ".join(", ".join(refused).rsplit(", ", 1))
        raise Forbidden(
            f"A {principal.role} key may not {'set' if creating else 'change'} {what} of a "
            "user; that is for the fleet's staff or an admin."
        )


def _given(body: UserIn, reset_model: bool) -> list[str]:
    """The fields the request sets: the body's fields it gives, and ``reset_model`` if true."""
    names = [name for name in type(body).model_fields if getattr(body, name) is not None]
    return [*names, "reset_model"] if reset_model else names


def put_user(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    body: UserIn,
    *,
    reset_model: bool,
    fleet: str | None = None,
) -> tuple[UserOut, bool]:
    """Create or update a user of the caller's fleet (an admin's: of ``fleet``); (user,
    created). Who may set which field is ``USER_FIELD_RIGHTS`` (403 otherwise); a change of
    learner or of ``fleet_prior`` is audited (``user.learner``, ``user.prior``)."""
    in_fleet = fleet_of(principal, fleet, user_id)
    given = _given(body, reset_model)
    created = False
    if repo.lock(session, in_fleet, user_id) is None:
        _check_rights(principal, given, creating=True)
        created = create_user(
            session,
            ctx,
            in_fleet,
            user_id,
            spec=body.learner,
            display_name=body.display_name,
            fleet_prior=body.fleet_prior,
        )
    user = visible_user(session, principal, user_id, fleet=in_fleet, lock=True)
    if created:
        return user_out(user), True
    model = PersonModel.open(session, ctx, user, write=True)
    learner: TabularLearner[Any] | None = None
    learner_error: ValidationFailed | None = None
    if body.learner is not None:
        try:
            learner = fresh_learner(
                body.learner.algorithm,
                body.learner.params,
                ctx.missions.get(session, user.fleet, model.mission_version).mission,
            )
        except ValidationFailed as exc:  # not the stored learner: refused or 422, below
            learner_error = exc
    same = {
        "display_name": body.display_name == user.display_name,
        "fleet_prior": body.fleet_prior == user.fleet_prior,
        "learner": learner is not None
        and body.learner is not None
        and (body.learner.algorithm, learner.params.to_dict())
        == (user.algorithm, dict(user.params)),
    }
    _check_rights(principal, [n for n in given if not same.get(n, False)], creating=False)
    if learner_error is not None:
        raise learner_error
    if body.display_name is not None:
        user.display_name = body.display_name
    if body.fleet_prior is not None and body.fleet_prior != user.fleet_prior:
        user.fleet_prior = body.fleet_prior
        audit.record(
            session,
            principal,
            "user.prior",
            target=user_id,
            fleet=user.fleet,
            detail={"fleet_prior": user.fleet_prior},
        )
    if learner is not None and body.learner is not None and not same["learner"]:
        if user.episode_count > 0 and not reset_model:
            raise Conflict(
                f"User {user_id!r} has {user.episode_count} episodes; changing the learner "
                "forgets what was learned. Repeat with ?reset_model=true to do so."
            )
        before = user.algorithm
        user.algorithm, user.params = body.learner.algorithm, learner.params.to_dict()
        model.reset(
            learner,
            actor=principal,
            cause="learner",
            action="user.learner",
            detail={
                "algorithm": user.algorithm,
                "was": before,
                "episodes": user.episode_count,
            },
        )
        model.save()
    repo.save_profile(session, user)
    return user_out(user), False


def get_user(
    session: Session, principal: Principal, user_id: str, *, fleet: str | None = None
) -> UserOut:
    return user_out(visible_user(session, principal, user_id, fleet=fleet))


def _cursor(user: UserRow) -> str:
    raw = f"{user.fleet}/{user.user_id}".encode()
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def _after(cursor: str | None, fleet: str | None) -> tuple[str, str] | None:
    """(fleet, user id) a cursor stands for. A cursor of a list of one fleet given before
    fleets had ids of their own (a bare user id) still reads, in the listed fleet."""
    if cursor is None:
        return None
    try:
        # validate=True: characters outside the alphabet are refused, not silently dropped
        text = base64.b64decode(
            cursor + "=" * (-len(cursor) % 4), altchars=b"-_", validate=True
        ).decode()
    except (binascii.Error, UnicodeDecodeError, ValueError):
        text = ""
    in_fleet, slash, user_id = text.rpartition("/")
    if not slash:
        in_fleet = fleet or ""
    if not re.fullmatch(CLIENT_ID_PATTERN, user_id) or (
        in_fleet and not re.fullmatch(CLIENT_ID_PATTERN, in_fleet)
    ):
        raise ValidationFailed("cursor is not one this API returned.")
    return in_fleet, user_id


def list_users(
    session: Session,
    principal: Principal,
    *,
    limit: int,
    cursor: str | None,
    fleet: str | None = None,
) -> UserList:
    """The users of the caller's fleet, a page at a time; an admin's: of every fleet (by fleet,
    then user id), or of the one it names."""
    if fleet is not None and not principal.sees(fleet):
        raise NotFound(f"No fleet {fleet!r} you can see.")
    listed = fleet if fleet is not None else (None if principal.is_admin else principal.fleet)
    rows = repo.list_page(session, fleet=listed, after=_after(cursor, listed), limit=limit + 1)
    items = [user_out(u) for u in rows[:limit]]
    more = len(rows) > limit
    return UserList(items=items, next_cursor=_cursor(rows[limit - 1]) if more else None)


def delete_user(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    *,
    fleet: str | None = None,
) -> None:
    """Erase a person: their row and every row that refers to it (the model, its journal and
    snapshots, episodes, decisions, answers, feedback, corrections and their notes: the
    foreign keys cascade), their rows in the fleet's evaluation results, and, in the audit log,
    the details of the entries about them (``{"erased": true}``: who did what to which id, and
    when, stay). The erasure's own entry
    holds nothing of the person either. The learner leaves this process's cache; the other
    workers' never find it again (a user's number is never reused)."""
    require_manager(principal)
    user = visible_user(session, principal, user_id, fleet=fleet, lock=True)
    repo.delete_user(session, user)
    # The per-person rows of the fleet's evaluation results name them: removed.
    evaluations_repo.forget_person(session, user.fleet, user_id)
    redacted = audit_repo.redact_erased(
        session, fleet=user.fleet, user_id=user_id, prefixes=audit.ABOUT_A_USER
    )
    audit.record(
        session,
        principal,
        "user.delete",
        target=user_id,
        fleet=user.fleet,
        detail=dict(audit_repo.ERASED),
    )
    ctx.cache.drop(user.id)
    log.info(
        "erased user %s of fleet %s (%d audit entries about them blanked)",
        user_id,
        user.fleet,
        redacted,
    )
