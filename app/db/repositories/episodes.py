"""The episode aggregate: an episode, its decisions (and what the person did), its feedback."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy import and_, bindparam, func, insert, select, update
from sqlalchemy.orm import Session

from ..models import Decision, Episode, Feedback, LearnerModel, User
from ._rows import Prepared, columns, conn, names, record, table, values
from .models import ModelRow

__all__ = [
    "DecisionRow",
    "EpisodeRow",
    "FeedbackRow",
    "HistoryAnswer",
    "HistoryEpisode",
    "MetricRow",
    "add_feedback",
    "by_event",
    "by_seq",
    "decision",
    "decisions",
    "decisions_for_rebuild",
    "feedback",
    "feedback_list",
    "get",
    "history",
    "insert_decisions",
    "insert_episode",
    "interrupt_open",
    "list_page",
    "local_time",
    "load_for_outcome",
    "metric_rows",
    "mission_versions",
    "occurred_at_of",
    "owner",
    "save_answer",
    "save_episode",
]


@dataclass(slots=True)
class EpisodeRow:
    id: str
    user_pk: int
    seq: int  # the user's 1-based episode index
    learner_episode: int  # seq + the model's episode offset
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
    mission_version: int  # the fleet's mission version the episode started (and ends) under
    utc_offset: int | None = None  # minutes east of UTC that occurred_at came with


@dataclass(slots=True)
class DecisionRow:
    id: str
    episode_id: str
    position: int
    state: int
    action: int
    probabilities: list[float]
    chain: list[dict[str, Any]]
    draw: int | None  # position in the user's seed stream
    forced: bool  # the person chose the action (a request)
    model_version: int  # the model it was drawn from
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


@dataclass(slots=True)
class FeedbackRow:
    episode_id: str
    feedback_id: str
    feedback: str
    reward: float
    received_at: dt.datetime
    request_hash: str
    response: dict[str, Any]


@dataclass(frozen=True, slots=True)
class MetricRow:
    seq: int
    initiated: bool
    interaction_class: str
    success: bool
    queries: int
    total_reward: float


_episodes = table(Episode)
_decisions = table(Decision)
_feedback = table(Feedback)
_models = table(LearnerModel)
_users = table(User)

_EPISODE_COLS = columns(_episodes, EpisodeRow)
_DECISION_COLS = columns(_decisions, DecisionRow)
_N_EPISODE = len(_EPISODE_COLS)
_N_MODEL = len(columns(_models, ModelRow))
_EPISODE_NAMES = names(EpisodeRow)
_DECISION_NAMES = names(DecisionRow)
# What an outcome or feedback changes in its episode (the rest, the stored response too, is set
# when it is created).
_EPISODE_MUTABLE = (
    "status",
    "state",
    "total_reward",
    "interaction_class",
    "initiated",
    "success",
    "queries",
    "closed_at",
)
_ANSWER = (
    "response",
    "service",
    "detail",
    "feedback",
    "reward",
    "next_state",
    "answered_at",
    "outcome_hash",
    "outcome_response",
)

_LATEST = (
    select(func.max(_decisions.c.position))
    .where(_decisions.c.episode_id == _episodes.c.id)
    .correlate(_episodes)
    .scalar_subquery()
)
_FOR_OUTCOME = Prepared(
    select(*_EPISODE_COLS, *columns(_models, ModelRow), *_DECISION_COLS)
    .join(_models, _models.c.user_pk == _episodes.c.user_pk)
    .outerjoin(
        _decisions,
        and_(_decisions.c.episode_id == _episodes.c.id, _decisions.c.position == _LATEST),
    )
    .where(_episodes.c.id == bindparam("episode_id"))
)
_GET = select(*_EPISODE_COLS).where(_episodes.c.id == bindparam("episode_id"))
_OWNER = (
    select(_users.c.id, _users.c.fleet, _users.c.user_id)
    .join(_users, _users.c.id == _episodes.c.user_pk)
    .where(_episodes.c.id == bindparam("episode_id"))
)
_DECISION = Prepared(
    select(*_DECISION_COLS).where(
        _decisions.c.id == bindparam("decision_id"),
        _decisions.c.episode_id == bindparam("episode_id"),
    )
)
_DECISIONS = (
    select(*_DECISION_COLS)
    .where(_decisions.c.episode_id == bindparam("episode_id"))
    .order_by(_decisions.c.position)
)
_BY_EVENT = Prepared(
    select(_episodes.c.request_hash, _episodes.c.response).where(
        _episodes.c.user_pk == bindparam("user_pk"), _episodes.c.event_id == bindparam("event_id")
    )
)
_FEEDBACK_COLS = columns(_feedback, FeedbackRow)
_FEEDBACK = select(*_FEEDBACK_COLS).where(
    _feedback.c.episode_id == bindparam("episode_id"),
    _feedback.c.feedback_id == bindparam("feedback_id"),
)
_FEEDBACK_LIST = (
    select(*_FEEDBACK_COLS)
    .where(_feedback.c.episode_id == bindparam("episode_id"))
    .order_by(_feedback.c.id)
)
_INSERT_EPISODE = Prepared(insert(_episodes), keyed=True)
_INSERT_DECISION = Prepared(insert(_decisions), keyed=True)
_INSERT_FEEDBACK = insert(_feedback)
# Updates: the SET columns are the keys of the parameters; the row's key is a "b_" parameter.
_UPDATE_DECISION = Prepared(
    update(_decisions).where(_decisions.c.id == bindparam("b_id")), keyed=True
)
_UPDATE_EPISODE = Prepared(update(_episodes).where(_episodes.c.id == bindparam("b_id")), keyed=True)


def load_for_outcome(
    session: Session, episode_id: str
) -> tuple[EpisodeRow, ModelRow, DecisionRow | None] | None:
    """The episode, its user's model head and its current (latest) decision, in one query."""
    row = _FOR_OUTCOME.first(session, {"episode_id": episode_id})
    if row is None:
        return None
    v = tuple(row)
    rest = v[_N_EPISODE + _N_MODEL :]
    return (
        EpisodeRow(*v[:_N_EPISODE]),
        ModelRow(*v[_N_EPISODE : _N_EPISODE + _N_MODEL]),
        DecisionRow(*rest) if rest[0] is not None else None,
    )


def get(session: Session, episode_id: str) -> EpisodeRow | None:
    return record(EpisodeRow, conn(session).execute(_GET, {"episode_id": episode_id}).first())


def owner(session: Session, episode_id: str) -> tuple[int, str, str] | None:
    """(user pk, fleet, user id) of an episode's user, without loading the episode."""
    row = conn(session).execute(_OWNER, {"episode_id": episode_id}).first()
    return None if row is None else (row[0], row[1], row[2])


def by_event(session: Session, user_pk: int, event_id: str) -> tuple[str, dict[str, Any]] | None:
    """(request hash, stored response) of the episode an event opened, if any."""
    row = _BY_EVENT.first(session, {"user_pk": user_pk, "event_id": event_id})
    return None if row is None else (row[0], row[1])


def decision(session: Session, episode_id: str, decision_id: str) -> DecisionRow | None:
    return record(
        DecisionRow,
        _DECISION.first(session, {"decision_id": decision_id, "episode_id": episode_id}),
    )


def decisions(session: Session, episode_id: str) -> list[DecisionRow]:
    """The episode's decisions in order."""
    return [
        DecisionRow(*row) for row in conn(session).execute(_DECISIONS, {"episode_id": episode_id})
    ]


def insert_episode(session: Session, episode: EpisodeRow) -> None:
    _INSERT_EPISODE.run(session, values(episode, _EPISODE_NAMES))


def save_episode(session: Session, episode: EpisodeRow) -> None:
    _UPDATE_EPISODE.run(session, {"b_id": episode.id, **values(episode, _EPISODE_MUTABLE)})


def insert_decisions(session: Session, rows: list[DecisionRow]) -> None:
    _INSERT_DECISION.run_many(session, [values(r, _DECISION_NAMES) for r in rows])


def save_answer(session: Session, row: DecisionRow) -> None:
    """Store the person's response to a decision and the outcome request's response."""
    _UPDATE_DECISION.run(session, {"b_id": row.id, **values(row, _ANSWER)})


def feedback(session: Session, episode_id: str, feedback_id: str) -> FeedbackRow | None:
    return record(
        FeedbackRow,
        conn(session)
        .execute(_FEEDBACK, {"episode_id": episode_id, "feedback_id": feedback_id})
        .first(),
    )


def feedback_list(session: Session, episode_id: str) -> list[FeedbackRow]:
    return [
        FeedbackRow(*row)
        for row in conn(session).execute(_FEEDBACK_LIST, {"episode_id": episode_id})
    ]


def add_feedback(session: Session, row: FeedbackRow) -> None:
    conn(session).execute(_INSERT_FEEDBACK, [values(row, names(FeedbackRow))])


def interrupt_open(session: Session, user_pk: int, *, at: dt.datetime) -> int:
    """Close the user's open episodes as ``interrupted`` (their mission was replaced); how
    many."""
    result = conn(session).execute(
        update(_episodes)
        .where(_episodes.c.user_pk == user_pk, _episodes.c.status == "open")
        .values(status="interrupted", closed_at=at)
    )
    return int(result.rowcount or 0)


def by_seq(session: Session, user_pk: int, seq: int) -> tuple[dt.datetime, int | None] | None:
    """When the user's episode ``seq`` happened, and the offset it came with."""
    row = (
        conn(session)
        .execute(
            select(_episodes.c.occurred_at, _episodes.c.utc_offset).where(
                _episodes.c.user_pk == user_pk, _episodes.c.seq == seq
            )
        )
        .first()
    )
    return None if row is None else (row[0], row[1])


def mission_versions(session: Session, user_pk: int) -> list[int]:
    """The fleet's mission versions the user's stored episodes ran under."""
    return list(
        conn(session)
        .execute(
            select(_episodes.c.mission_version)
            .where(_episodes.c.user_pk == user_pk)
            .distinct()
            .order_by(_episodes.c.mission_version)
        )
        .scalars()
    )


def list_page(
    session: Session, user_pk: int, *, before_seq: int | None, limit: int
) -> list[EpisodeRow]:
    """A user's episodes, newest first, before ``before_seq``."""
    stmt = (
        select(*_EPISODE_COLS)
        .where(_episodes.c.user_pk == user_pk)
        .order_by(_episodes.c.seq.desc())
        .limit(limit)
    )
    if before_seq is not None:
        stmt = stmt.where(_episodes.c.seq < before_seq)
    return [EpisodeRow(*row) for row in conn(session).execute(stmt)]


def metric_rows(session: Session, user_pk: int, *, last: int | None) -> list[MetricRow]:
    """The figures of the user's last ``last`` episodes (all: ``None``), oldest first."""
    stmt = (
        select(
            _episodes.c.seq,
            _episodes.c.initiated,
            _episodes.c.interaction_class,
            _episodes.c.success,
            _episodes.c.queries,
            _episodes.c.total_reward,
        )
        .where(_episodes.c.user_pk == user_pk)
        .order_by(_episodes.c.seq.desc())
    )
    if last is not None:
        stmt = stmt.limit(last)
    rows = [MetricRow(*row) for row in conn(session).execute(stmt)]
    return rows[::-1]


def decisions_for_rebuild(
    session: Session, user_pk: int, version: int
) -> list[tuple[DecisionRow, int, int]]:
    """Drawn decisions of the user from model ``version`` on, in draw order: (decision,
    context, learner's episode index)."""
    stmt = (
        select(*_DECISION_COLS, _episodes.c.context, _episodes.c.learner_episode)
        .join(_episodes, _episodes.c.id == _decisions.c.episode_id)
        .where(
            _episodes.c.user_pk == user_pk,
            _decisions.c.draw.is_not(None),
            _decisions.c.model_version >= version,
        )
        .order_by(_decisions.c.draw)
    )
    n = len(_DECISION_COLS)
    return [(DecisionRow(*row[:n]), row[n], row[n + 1]) for row in conn(session).execute(stmt)]


@dataclass(slots=True)
class HistoryEpisode:
    """An episode as the person's profile reads it."""

    seq: int
    learner_episode: int
    time_slot: str
    situation: str
    status: str
    occurred_at: dt.datetime
    utc_offset: int | None
    request_service: str | None
    request_detail: str | None
    mission_version: int


@dataclass(slots=True)
class HistoryAnswer:
    """What the person did after one of the robot's decisions (forced ones excluded)."""

    seq: int
    action: int
    response: str
    service: str | None
    detail: str | None


def history(
    session: Session, user_pk: int, *, after_seq: int = 0, upto_seq: int | None = None
) -> tuple[list[HistoryEpisode], list[HistoryAnswer]]:
    """The user's episodes after ``after_seq`` (up to ``upto_seq``), oldest first, and the
    person's answers to the robot's own decisions in them, in order."""
    c = conn(session)
    span = [_episodes.c.user_pk == user_pk, _episodes.c.seq > after_seq]
    if upto_seq is not None:
        span.append(_episodes.c.seq <= upto_seq)
    eps = c.execute(
        select(*[_episodes.c[n] for n in names(HistoryEpisode)])
        .where(*span)
        .order_by(_episodes.c.seq)
    )
    answers = c.execute(
        select(
            _episodes.c.seq,
            _decisions.c.action,
            _decisions.c.response,
            _decisions.c.service,
            _decisions.c.detail,
        )
        .join(_episodes, _episodes.c.id == _decisions.c.episode_id)
        .where(
            *span,
            _decisions.c.response.is_not(None),
            _decisions.c.forced.is_(False),
        )
        .order_by(_episodes.c.seq, _decisions.c.position)
    )
    return ([HistoryEpisode(*row) for row in eps], [HistoryAnswer(*row) for row in answers])


def occurred_at_of(session: Session, user_pk: int, learner_episode: int) -> dt.datetime | None:
    """When the user's episode of learner index ``learner_episode`` happened, in the local time
    it was reported in (``None``: no such episode)."""
    row = (
        conn(session)
        .execute(
            select(_episodes.c.occurred_at, _episodes.c.utc_offset).where(
                _episodes.c.user_pk == user_pk, _episodes.c.learner_episode == learner_episode
            )
        )
        .first()
    )
    return None if row is None else local_time(row[0], row[1])


def local_time(at: dt.datetime, utc_offset: int | None) -> dt.datetime:
    """``at`` in the offset it was reported with (UTC when it was not stored)."""
    if utc_offset is None:
        return at.astimezone(dt.UTC)
    return at.astimezone(dt.timezone(dt.timedelta(minutes=utc_offset)))
