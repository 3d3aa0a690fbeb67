"""The robots' write path (start an episode, report an outcome) in SQLAlchemy Core.

These two requests are most of a fleet's traffic, so they skip the ORM's unit of work: each
reads what it needs in as few statements as it can (the user lock, then the episode with its
model's version and its current decision in one query) and writes each changed table with one
statement. The rows travel as the plain records below; the ORM classes stay the schema and serve
every other path.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, fields
from typing import Any

from sqlalchemy import Connection, Table, and_, bindparam, func, insert, select, update

from ..models import Decision, Episode, LearnerModel, Sample, User

__all__ = [
    "DecisionRec",
    "EpisodeRec",
    "ModelRec",
    "UserRec",
    "decision_by_id",
    "episode_by_event",
    "insert_decisions",
    "insert_episode",
    "load_episode",
    "lock_user",
    "lock_user_of_episode",
    "model_of",
    "model_state",
    "save_answer",
    "save_episode",
    "save_model",
    "save_user_counters",
]

_users: Table = User.__table__  # type: ignore[assignment]
_models: Table = LearnerModel.__table__  # type: ignore[assignment]
_episodes: Table = Episode.__table__  # type: ignore[assignment]
_decisions: Table = Decision.__table__  # type: ignore[assignment]
_samples: Table = Sample.__table__  # type: ignore[assignment]


@dataclass(slots=True)
class UserRec:
    """The locked user: who may see it and the two counters the write path moves."""

    user_id: str
    fleet: str
    episode_count: int
    draws: int


@dataclass(slots=True)
class ModelRec:
    """A user's model row without its state document (loaded only when the cache misses)."""

    version: int
    base_version: int
    episode_offset: int


@dataclass(slots=True)
class EpisodeRec:
    id: str
    user_id: str
    seq: int
    learner_episode: int
    event_id: str
    robot_id: str | None
    occurred_at: dt.datetime
    time_slot: str
    situation: str
    context: int
    initiator: str
    request_service: str | None
    request_detail: str | None
    status: str
    state: int
    total_reward: float
    interaction_class: str
    initiated: bool
    success: bool
    queries: int
    request_hash: str
    response: dict[str, Any]
    created_at: dt.datetime
    closed_at: dt.datetime | None


@dataclass(slots=True)
class DecisionRec:
    id: str
    episode_id: str
    position: int
    state: int
    action: int
    probabilities: list[float]
    chain: list[dict[str, Any]]
    draw: int | None
    forced: bool
    model_version: int
    decided_at: dt.datetime
    response: str | None = None
    service: str | None = None
    detail: str | None = None
    feedback: str | None = None
    reward: float | None = None
    next_state: int | None = None
    answered_at: dt.datetime | None = None
    outcome_hash: str | None = None
    outcome_response: dict[str, Any] | None = None


_EPISODE_COLS = [_episodes.c[f.name] for f in fields(EpisodeRec)]
_DECISION_COLS = [_decisions.c[f.name] for f in fields(DecisionRec)]
_N_EPISODE = len(_EPISODE_COLS)
_EPISODE_NAMES = tuple(f.name for f in fields(EpisodeRec))
_DECISION_NAMES = tuple(f.name for f in fields(DecisionRec))
# What an outcome changes in its episode (the rest, the stored response too, is set when it is
# created).
_EPISODE_MUTABLE = ("status", "state", "total_reward", "interaction_class", "initiated",
                    "success", "queries", "closed_at")
_ANSWER = ("response", "service", "detail", "feedback", "reward", "next_state", "answered_at",
           "outcome_hash", "outcome_response")


def _user(row: Any) -> UserRec | None:
    return None if row is None else UserRec(*row)


# The statements are built once: constructing a Core statement costs more than executing a
# cached one (SQLAlchemy compiles each shape once and reuses it; the building is ours to skip).
_USER_COLS = (_users.c.user_id, _users.c.fleet, _users.c.episode_count, _users.c.draws)
_LOCK_USER = select(*_USER_COLS).where(_users.c.user_id == bindparam("user_id")
                                       ).with_for_update()
_LOCK_OWNER = select(*_USER_COLS).where(_users.c.user_id == select(_episodes.c.user_id).where(
    _episodes.c.id == bindparam("episode_id")).scalar_subquery()).with_for_update()
_MODEL = select(_models.c.version, _models.c.base_version, _models.c.episode_offset).where(
    _models.c.user_id == bindparam("user_id"))
_MODEL_STATE = select(_models.c.state).where(_models.c.user_id == bindparam("user_id"))
_LATEST = (select(func.max(_decisions.c.position))
           .where(_decisions.c.episode_id == _episodes.c.id)
           .correlate(_episodes).scalar_subquery())
_EPISODE = (
    select(*_EPISODE_COLS, _models.c.version, _models.c.base_version, _models.c.episode_offset,
           *_DECISION_COLS)
    .join(_models, _models.c.user_id == _episodes.c.user_id)
    .outerjoin(_decisions, and_(_decisions.c.episode_id == _episodes.c.id,
                                _decisions.c.position == _LATEST))
    .where(_episodes.c.id == bindparam("episode_id"))
)
_DECISION = select(*_DECISION_COLS).where(_decisions.c.id == bindparam("decision_id"),
                                          _decisions.c.episode_id == bindparam("episode_id"))
_BY_EVENT = select(_episodes.c.request_hash, _episodes.c.response).where(
    _episodes.c.user_id == bindparam("user_id"), _episodes.c.event_id == bindparam("event_id"))
_INSERT_EPISODE = insert(_episodes)
_INSERT_DECISION = insert(_decisions)
_INSERT_SAMPLE = insert(_samples)
# Updates: the SET columns are the keys of the parameters; the row's key is a "b_" parameter.
_UPDATE_DECISION = update(_decisions).where(_decisions.c.id == bindparam("b_id"))
_UPDATE_EPISODE = update(_episodes).where(_episodes.c.id == bindparam("b_id"))
_UPDATE_USER = update(_users).where(_users.c.user_id == bindparam("b_id"))
_UPDATE_MODEL = update(_models).where(_models.c.user_id == bindparam("b_id"))


def lock_user(conn: Connection, user_id: str) -> UserRec | None:
    """The user, locked for this transaction (PostgreSQL: ``FOR UPDATE``; SQLite's write
    transactions already hold the database's write lock)."""
    return _user(conn.execute(_LOCK_USER, {"user_id": user_id}).first())


def lock_user_of_episode(conn: Connection, episode_id: str) -> UserRec | None:
    """The user who owns an episode, locked as by :func:`lock_user`; ``None`` if no episode.

    The lock comes first and alone: on PostgreSQL a statement that waited for it sees the rows
    committed by the previous holder only if it starts after the wait (READ COMMITTED), so the
    episode is read by the next statement.
    """
    return _user(conn.execute(_LOCK_OWNER, {"episode_id": episode_id}).first())


def model_of(conn: Connection, user_id: str) -> ModelRec | None:
    row = conn.execute(_MODEL, {"user_id": user_id}).first()
    return None if row is None else ModelRec(*row)


def model_state(conn: Connection, user_id: str) -> dict[str, Any]:
    """The model's state document (decoded JSON)."""
    state: dict[str, Any] = conn.execute(_MODEL_STATE, {"user_id": user_id}).scalar_one()
    return state


def load_episode(conn: Connection, episode_id: str
                 ) -> tuple[EpisodeRec, ModelRec, DecisionRec | None] | None:
    """The episode, its user's model (without state) and its current (latest) decision."""
    row = conn.execute(_EPISODE, {"episode_id": episode_id}).first()
    if row is None:
        return None
    values = tuple(row)
    episode = EpisodeRec(*values[:_N_EPISODE])
    model = ModelRec(*values[_N_EPISODE:_N_EPISODE + 3])
    rest = values[_N_EPISODE + 3:]
    return episode, model, (DecisionRec(*rest) if rest[0] is not None else None)


def decision_by_id(conn: Connection, episode_id: str, decision_id: str) -> DecisionRec | None:
    row = conn.execute(_DECISION, {"decision_id": decision_id, "episode_id": episode_id}).first()
    return None if row is None else DecisionRec(*row)


def episode_by_event(conn: Connection, user_id: str, event_id: str
                     ) -> tuple[str, dict[str, Any]] | None:
    """(request hash, stored response) of the episode an event opened, if any."""
    row = conn.execute(_BY_EVENT, {"user_id": user_id, "event_id": event_id}).first()
    return None if row is None else (row[0], row[1])


def _values(rec: Any, names: tuple[str, ...]) -> dict[str, Any]:
    return {name: getattr(rec, name) for name in names}


def insert_episode(conn: Connection, episode: EpisodeRec) -> None:
    conn.execute(_INSERT_EPISODE, [_values(episode, _EPISODE_NAMES)])


def insert_decisions(conn: Connection, rows: list[DecisionRec]) -> None:
    if rows:
        conn.execute(_INSERT_DECISION, [_values(r, _DECISION_NAMES) for r in rows])


def save_answer(conn: Connection, row: DecisionRec) -> None:
    """Store the person's response to a decision and the outcome request's response."""
    conn.execute(_UPDATE_DECISION, {"b_id": row.id, **_values(row, _ANSWER)})


def save_episode(conn: Connection, episode: EpisodeRec) -> None:
    conn.execute(_UPDATE_EPISODE, {"b_id": episode.id, **_values(episode, _EPISODE_MUTABLE)})


def save_user_counters(conn: Connection, user: UserRec) -> None:
    conn.execute(_UPDATE_USER, {"b_id": user.user_id, "episode_count": user.episode_count,
                                "draws": user.draws})


def save_model(conn: Connection, user_id: str, *, version: int, state: dict[str, Any],
               updated_at: dt.datetime, samples: list[dict[str, Any]]) -> None:
    """The model's new version and state, and the samples that made it (its journal)."""
    conn.execute(_UPDATE_MODEL, {"b_id": user_id, "version": version, "state": state,
                                 "updated_at": updated_at})
    if samples:
        conn.execute(_INSERT_SAMPLE, samples)
