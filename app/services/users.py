"""Users: create or update, read, list, delete; and who may see whom."""

from __future__ import annotations

import base64
import binascii
import re

from sqlalchemy.orm import Session

from app.db.repositories import models as models_repo
from app.db.repositories import users as repo
from app.db.repositories.users import UserRow
from app.db.types import utcnow
from app.errors import Conflict, NotFound, ValidationFailed
from app.schemas.common import CLIENT_ID_PATTERN
from app.schemas.users import LearnerSpec, UserIn, UserList, UserOut

from . import audit
from .auth import require_admin
from .context import Principal, ServiceContext
from .learners import fresh_learner, save_learner

__all__ = ["create_user", "delete_user", "get_user", "list_users", "put_user", "user_out",
           "visible_user"]


def visible_user(session: Session, principal: Principal, user_id: str, *,
                 lock: bool = False) -> UserRow:
    """The user, if the caller may see it (locked for the transaction with ``lock``); another
    fleet's user is reported as absent (404)."""
    user = repo.lock(session, user_id) if lock else repo.get(session, user_id)
    return _visible(principal, user_id, user)


def _visible(principal: Principal, user_id: str, user: UserRow | None) -> UserRow:
    if user is None or (not principal.is_admin and user.fleet != principal.fleet):
        raise NotFound(f"No user {user_id!r} in your fleet.")
    return user


def user_out(user: UserRow) -> UserOut:
    return UserOut(
        user_id=user.user_id, fleet=user.fleet, display_name=user.display_name,
        learner=LearnerSpec(algorithm=user.algorithm, params=dict(user.params)),
        created_at=user.created_at, episodes=user.episode_count,
    )


def create_user(session: Session, ctx: ServiceContext, principal: Principal, user_id: str, *,
                spec: LearnerSpec | None = None, display_name: str | None = None) -> bool:
    """Create the user in the caller's fleet with a fresh learner, unless it exists; True when
    created. (Two requests creating the same user at once: one creates it, both go on.)"""
    spec = spec or LearnerSpec()
    learner = fresh_learner(ctx, spec.algorithm, spec.params)
    return repo.create(session, user_id=user_id, fleet=principal.fleet,
                       algorithm=spec.algorithm, params=learner.params.to_dict(),
                       display_name=display_name, state=learner.to_state(), now=utcnow())


def put_user(
    session: Session, ctx: ServiceContext, principal: Principal, user_id: str, body: UserIn,
    *, reset_model: bool,
) -> tuple[UserOut, bool]:
    """Create or update a user; (user, created)."""
    existing = repo.lock(session, user_id)
    created = False
    if existing is None:
        created = create_user(session, ctx, principal, user_id, spec=body.learner,
                              display_name=body.display_name)
    user = visible_user(session, principal, user_id, lock=True)
    if created:
        return user_out(user), True
    if body.display_name is not None:
        user.display_name = body.display_name
    if body.learner is not None:
        learner = fresh_learner(ctx, body.learner.algorithm, body.learner.params)
        params = learner.params.to_dict()
        if (body.learner.algorithm, params) != (user.algorithm, dict(user.params)):
            if user.episode_count > 0 and not reset_model:
                raise Conflict(
                    f"User {user_id!r} has {user.episode_count} episodes; changing the learner "
                    "forgets what was learned. Repeat with ?reset_model=true to do so."
                )
            user.algorithm, user.params = body.learner.algorithm, params
            model = models_repo.head(session, user_id)
            assert model is not None  # every user is created with its model
            save_learner(session, ctx, user_id, model, learner, start_over="fresh")
    repo.save_profile(session, user)
    return user_out(user), False


def get_user(session: Session, principal: Principal, user_id: str) -> UserOut:
    return user_out(visible_user(session, principal, user_id))


def _cursor(user_id: str) -> str:
    return base64.urlsafe_b64encode(user_id.encode()).decode().rstrip("=")


def _after(cursor: str | None) -> str | None:
    if cursor is None:
        return None
    try:
        # validate=True: characters outside the alphabet are refused, not silently dropped
        after = base64.b64decode(cursor + "=" * (-len(cursor) % 4), altchars=b"-_",
                                 validate=True).decode()
    except (binascii.Error, UnicodeDecodeError, ValueError):
        after = ""
    if not re.fullmatch(CLIENT_ID_PATTERN, after):
        raise ValidationFailed("cursor is not one this API returned.")
    return after


def list_users(
    session: Session, principal: Principal, *, limit: int, cursor: str | None
) -> UserList:
    fleet = None if principal.is_admin else principal.fleet
    rows = repo.list_page(session, fleet=fleet, after=_after(cursor), limit=limit + 1)
    items = [user_out(u) for u in rows[:limit]]
    more = len(rows) > limit
    return UserList(items=items, next_cursor=_cursor(rows[limit - 1].user_id) if more else None)


def delete_user(session: Session, ctx: ServiceContext, principal: Principal, user_id: str
                ) -> None:
    require_admin(principal)
    user = visible_user(session, principal, user_id, lock=True)
    audit.record(session, principal, "user.delete", target=user_id, fleet=user.fleet,
                 detail={"episodes": user.episode_count})
    repo.delete_user(session, user_id)
    ctx.cache.drop(user_id)
