from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy import Row, delete, func, insert, select
from sqlalchemy.orm import Session

from ..models import Decision, Episode, Feedback, Sample, User

__all__ = [
    "add_samples",
    "decisions_for_rebuild",
    "delete_samples",
    "episode_owner",
    "get_episode",
    "get_feedback",
    "has_transition",
    "list_decisions",
    "list_episodes",
    "list_feedback",
    "metric_rows",
    "samples_since",
]


def episode_owner(session: Session, episode_id: str) -> Row[str, str] | None:
    """(user_id, fleet) of an episode, without loading it."""
    stmt = (
        select(Episode.user_id, User.fleet)
        .join(User, User.user_id == Episode.user_id)
        .where(Episode.id == episode_id)
    )
    return session.execute(stmt).first()


def get_episode(session: Session, episode_id: str) -> Episode | None:
    stmt = select(Episode).where(Episode.id == episode_id)
    return session.scalars(stmt.execution_options(populate_existing=True)).first()


def list_episodes(
    session: Session, user_id: str, *, before_seq: int | None, limit: int
) -> Sequence[Episode]:
    stmt = select(Episode).where(Episode.user_id == user_id).order_by(Episode.seq.desc())
    if before_seq is not None:
        stmt = stmt.where(Episode.seq < before_seq)
    return session.scalars(stmt.limit(limit)).all()


def list_decisions(session: Session, episode_id: str) -> Sequence[Decision]:
    stmt = select(Decision).where(Decision.episode_id == episode_id).order_by(Decision.position)
    return session.scalars(stmt).all()


def list_feedback(session: Session, episode_id: str) -> Sequence[Feedback]:
    stmt = select(Feedback).where(Feedback.episode_id == episode_id).order_by(Feedback.id)
    return session.scalars(stmt).all()


def get_feedback(session: Session, episode_id: str, feedback_id: str) -> Feedback | None:
    stmt = select(Feedback).where(
        Feedback.episode_id == episode_id, Feedback.feedback_id == feedback_id
    )
    return session.scalars(stmt).first()


def metric_rows(
    session: Session, user_id: str, *, last: int | None
) -> Sequence[Row[int, bool, str, bool, int, float]]:
    """(seq, initiated, interaction_class, success, queries, total_reward), oldest first."""
    stmt = (
        select(Episode.seq, Episode.initiated, Episode.interaction_class, Episode.success,
               Episode.queries, Episode.total_reward)
        .where(Episode.user_id == user_id)
        .order_by(Episode.seq.desc())
    )
    if last is not None:
        stmt = stmt.limit(last)
    rows = session.execute(stmt).all()
    return rows[::-1]


def add_samples(session: Session, rows: list[dict[str, Any]]) -> None:
    if rows:
        session.execute(insert(Sample), rows)


def samples_since(session: Session, user_id: str, version: int) -> Sequence[Sample]:
    stmt = (
        select(Sample)
        .where(Sample.user_id == user_id, Sample.version > version)
        .order_by(Sample.version, Sample.id)
    )
    return session.scalars(stmt).all()


def has_transition(session: Session, user_id: str, *, episode: int, action: int,
                   after_version: int) -> bool:
    """Whether the model taught after ``after_version`` holds ``action``'s sample of ``episode``."""
    stmt = select(Sample.id).where(
        Sample.user_id == user_id, Sample.episode == episode, Sample.action == action,
        Sample.kind == "transition", Sample.version > after_version,
    ).limit(1)
    return session.execute(stmt).first() is not None


def delete_samples(session: Session, user_id: str) -> None:
    session.execute(delete(Sample).where(Sample.user_id == user_id))


def decisions_for_rebuild(
    session: Session, user_id: str, version: int
) -> Sequence[Row[Decision, int, int]]:
    """Drawn decisions of the user from model ``version`` on: (decision, context, learner's
    episode index)."""
    stmt = (
        select(Decision, Episode.context, Episode.learner_episode)
        .join(Episode, Episode.id == Decision.episode_id)
        .where(Episode.user_id == user_id, Decision.draw.is_not(None),
               Decision.model_version >= version)
        .order_by(Decision.draw)
    )
    return session.execute(stmt).all()


def count_episodes(session: Session, user_id: str) -> int:
    stmt = select(func.count()).select_from(Episode).where(Episode.user_id == user_id)
    return int(session.scalar(stmt) or 0)
