"""Loading and saving a user's learner: the cache, the state document and the sample journal."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy import Connection
from sqlalchemy.orm import Session

from app.db.models import LearnerModel, User
from app.db.repositories import episodes as episodes_repo
from app.db.repositories import negotiation as neg
from app.db.repositories import users as users_repo
from app.db.types import utcnow
from app.errors import ValidationFailed
from app.learning import Transition, learner_from_state, make_learner
from app.learning.learners import TabularLearner

from .context import ServiceContext, after_commit

__all__ = ["fresh_learner", "learner_for_read", "learner_for_update", "learner_for_write",
           "save_feedback", "store_update"]


def fresh_learner(
    ctx: ServiceContext, algorithm: str, params: dict[str, Any] | None
) -> TabularLearner[Any]:
    """A new learner, or 422 naming what is wrong with the algorithm or its parameters."""
    try:
        return make_learner(algorithm, params, ctx.mission)
    except ValueError as exc:
        raise ValidationFailed(str(exc)) from None


def _model(session: Session, user: User) -> LearnerModel:
    model = users_repo.get_model(session, user.user_id)
    if model is None:  # every user is created with its model; only a broken database lacks it
        raise RuntimeError(f"user {user.user_id!r} has no model row")
    return model


def learner_for_update(
    session: Session, ctx: ServiceContext, user: User
) -> tuple[LearnerModel, TabularLearner[Any]]:
    """The user's model row and a learner holding its state; the caller holds the user lock."""
    model = _model(session, user)
    learner = ctx.cache.take(user.user_id, model.version)
    if learner is None:
        learner = learner_from_state(model.state, ctx.mission)
    return model, learner


def learner_for_read(
    session: Session, ctx: ServiceContext, user: User
) -> tuple[LearnerModel, TabularLearner[Any]]:
    """A private copy of the user's learner (readers never share the writers' objects)."""
    model = _model(session, user)
    return model, learner_from_state(model.state, ctx.mission)


def _commit_hook(session: Session, ctx: ServiceContext, user_id: str, model: LearnerModel,
                 learner: TabularLearner[Any]) -> None:
    version = model.version
    after_commit(session, lambda: ctx.cache.put(user_id, version, learner))


def learner_for_write(conn: Connection, ctx: ServiceContext, user_id: str, version: int
                      ) -> TabularLearner[Any]:
    """The robots' write path's learner at model ``version``: the cached one, else decoded from
    the stored state; the caller holds the user lock."""
    learner = ctx.cache.take(user_id, version)
    if learner is None:
        learner = learner_from_state(neg.model_state(conn, user_id), ctx.mission)
    return learner


def store_update(
    session: Session, conn: Connection, ctx: ServiceContext, user_id: str, model: neg.ModelRec,
    learner: TabularLearner[Any], transitions: Sequence[Transition],
) -> None:
    """Teach the learner one report's transitions and store state and journal together (one
    new version); the cache gets the learner back once the transaction commits."""
    if transitions:
        learner.update(transitions)
        model.version += 1
        neg.save_model(conn, user_id, version=model.version, state=learner.to_state(),
                       updated_at=utcnow(), samples=[
            {"user_id": user_id, "version": model.version, "kind": "transition",
             "episode": tr.episode, "context": tr.context, "state": tr.state,
             "action": tr.action, "reward": float(tr.reward), "next_state": tr.next_state,
             "signal": int(tr.signal)}
            for tr in transitions
        ])
    version = model.version
    after_commit(session, lambda: ctx.cache.put(user_id, version, learner))


def save_feedback(
    session: Session, ctx: ServiceContext, user: User, model: LearnerModel,
    learner: TabularLearner[Any], *, episode: int, context: int, state: int, action: int,
    reward: float,
) -> bool:
    """Add explicit feedback to a sample of the model; False when the model no longer has that
    sample (it was reset or replaced after the episode), in which case only history records it."""
    taught = episodes_repo.has_transition(session, user.user_id, episode=episode, action=action,
                                          after_version=model.base_version)
    try:
        if not taught:  # the sample predates a reset or an import: history keeps the feedback
            raise ValueError("the current model never learned this sample")
        learner.feedback(episode, context, action, reward)
    except ValueError:
        _commit_hook(session, ctx, user.user_id, model, learner)
        return False
    model.version += 1
    model.state = learner.to_state()
    model.updated_at = utcnow()
    episodes_repo.add_samples(session, [
        {"user_id": user.user_id, "version": model.version, "kind": "feedback",
         "episode": episode, "context": context, "state": state, "action": action,
         "reward": float(reward), "next_state": None, "signal": 0}
    ])
    _commit_hook(session, ctx, user.user_id, model, learner)
    return True


def replace_learner(
    session: Session, ctx: ServiceContext, user: User, learner: TabularLearner[Any], *,
    imported: bool,
) -> LearnerModel:
    """Start the user's model over from ``learner`` (a reset, a new algorithm, an import)."""
    model = _model(session, user)
    ctx.cache.drop(user.user_id)
    model.version += 1
    model.state = learner.to_state()
    model.base_state = model.state if imported else None
    model.base_version = model.version
    model.updated_at = utcnow()
    _commit_hook(session, ctx, user.user_id, model, learner)
    return model
