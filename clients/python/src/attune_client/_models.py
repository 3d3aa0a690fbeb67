"""Typed views of the API's JSON (pydantic v2).

Every model accepts fields it does not know (the contract lets the service add fields, and an
older client must keep working): they are kept, readable as attributes and in
``model_extra``. Strings whose set the contract fixes (an episode's ``status``, say) are
``Literal``; names that depend on the mission (actions, states, services) are plain ``str``.
"""

from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

__all__ = [
    "Action",
    "ActionBelief",
    "ActionProbability",
    "Context",
    "ContextBelief",
    "Decision",
    "EpisodePage",
    "EpisodeStarted",
    "EpisodeState",
    "EpisodeSummary",
    "EpisodeTrace",
    "FeedbackResult",
    "FlushReport",
    "LearnerSpec",
    "Mission",
    "MissionService",
    "ModelView",
    "OutcomeResult",
    "PendingReport",
    "Queued",
    "Rejection",
    "ServiceRequest",
    "StateBelief",
    "Stats",
    "TimeSlot",
    "TraceDecision",
    "TraceFeedback",
    "User",
    "UserPage",
]

EpisodeStatus = Literal["open", "closed"]
ReportKind = Literal["outcome", "feedback"]


class _Model(BaseModel):
    model_config = ConfigDict(extra="allow", frozen=True)


# -- actions and decisions ---------------------------------------------------------------------
class Action(_Model):
    """An action of the negotiation: ``kind`` (``initiate``, ``pass``, ``query_type``,
    ``query_detail``, ``perform``, or a silent one in ``chain``), with ``service`` and
    ``detail`` where it has them."""

    kind: str
    service: str | None = None
    detail: str | None = None


class ActionProbability(_Model):
    """An action and the probability it had (``p``)."""

    action: Action
    p: float


class Context(_Model):
    """Where an episode happens: the time slot (from the event's local time) and situation."""

    time_slot: str
    situation: str


class Decision(_Model):
    """What the robot must do now.

    ``action`` is to be carried out; ``expects`` lists the responses the outcome may report;
    ``probabilities`` is the distribution the action was drawn from; ``chain`` lists the silent
    steps the service took first, in order.
    """

    decision_id: str
    action: Action
    expects: list[str]
    probabilities: list[ActionProbability]
    chain: list[ActionProbability] = Field(default_factory=list)


class EpisodeStarted(_Model):
    """The answer to an event: the new episode and the robot's first decision.

    ``replayed`` is True when the service answered a repeated ``event_id`` (nothing changed).
    """

    episode_id: str
    user_id: str
    status: EpisodeStatus
    context: Context
    state: str
    total_reward: float
    decision: Decision | None
    replayed: bool = False


class EpisodeState(_Model):
    """An episode's status, state and reward so far."""

    episode_id: str
    status: EpisodeStatus
    state: str
    total_reward: float


class OutcomeResult(_Model):
    """The answer to an outcome: its reward, the episode, and the next decision (None when the
    episode ended). ``replayed`` is True when this repeats an earlier identical report."""

    reward: float
    episode: EpisodeState
    decision: Decision | None
    replayed: bool = False


class FeedbackResult(_Model):
    """The answer to feedback: its reward and the episode. ``replayed`` as for outcomes."""

    reward: float
    episode: EpisodeState
    replayed: bool = False


# -- users ---------------------------------------------------------------------------------------
class LearnerSpec(_Model):
    """A learner: the algorithm (``hri``, ``rmax``, ``qlearning``...) and its parameters
    (omitted ones keep the service's defaults)."""

    algorithm: str = "hri"
    params: dict[str, Any] = Field(default_factory=dict)


class ServiceRequest(_Model):
    """What a person asked for when they addressed the robot first."""

    service: str
    detail: str | None = None


class User(_Model):
    """A person the fleet serves."""

    user_id: str
    fleet: str
    display_name: str | None = None
    learner: LearnerSpec
    created_at: dt.datetime
    episodes: int


class UserPage(_Model):
    """One page of users; pass ``next_cursor`` back for the next (None on the last page)."""

    items: list[User]
    next_cursor: str | None = None


# -- episodes ------------------------------------------------------------------------------------
class TraceDecision(_Model):
    """One decision of an episode's trace, with the response it got (None while open)."""

    decision_id: str
    state: str
    action: Action
    probabilities: list[ActionProbability]
    chain: list[ActionProbability] = Field(default_factory=list)
    response: str | None = None
    service: str | None = None
    detail: str | None = None
    feedback: str | None = None
    reward: float | None = None
    decided_at: dt.datetime
    answered_at: dt.datetime | None = None


class TraceFeedback(_Model):
    """One piece of feedback of an episode's trace."""

    feedback_id: str
    feedback: str
    reward: float
    received_at: dt.datetime


class EpisodeSummary(_Model):
    """An episode without its trace (as listed)."""

    episode_id: str
    user_id: str
    event_id: str
    robot_id: str | None = None
    status: EpisodeStatus
    context: Context
    initiator: Literal["robot", "human"]
    interaction_class: Literal["I1", "I2", "I3", "none"]
    total_reward: float
    state: str | None = None
    occurred_at: dt.datetime | None = None
    index: int | None = None


class EpisodeTrace(EpisodeSummary):
    """An episode with every decision, response, reward and feedback."""

    decisions: list[TraceDecision]
    feedback: list[TraceFeedback]


class EpisodePage(_Model):
    """One page of a user's episodes, newest first."""

    items: list[EpisodeSummary]
    next_cursor: str | None = None


# -- inspection ----------------------------------------------------------------------------------
class ActionBelief(_Model):
    """What the learner believes about one action in one state. Fields the learner has no
    notion of are None."""

    action: Action
    q: float | None = None
    visits: int | None = None
    kept_visits: float | None = None
    since_last: int | None = None
    measure: float | None = None
    p: float | None = None


class StateBelief(_Model):
    """The actions of one state (a state of a service or detail names them)."""

    state: str
    service: str | None = None
    detail: str | None = None
    actions: list[ActionBelief]


class ContextBelief(_Model):
    """The learner's view of one context (time slot and situation)."""

    time_slot: str
    situation: str
    states: list[StateBelief]


class ModelView(_Model):
    """What a user's learner believes now; ``version`` goes up by one with every change."""

    user_id: str
    algorithm: str
    params: dict[str, Any] = Field(default_factory=dict)
    version: int
    episodes: int
    contexts: list[ContextBelief]


class Stats(_Model):
    """Metrics over a user's last episodes. The three rates are None when there is nothing to
    divide by (no episode, no mission)."""

    episodes: int
    missions: int
    interaction_rate: float | None
    success_rate: float | None
    queries_per_mission: float | None
    total_reward: float
    cumulative_reward: list[float]


class TimeSlot(_Model):
    """A time slot of the day, by local time (``"06:00"`` to ``"11:00"``)."""

    name: str
    start: str
    end: str


class MissionService(_Model):
    """A service the robots offer and its details."""

    name: str
    details: list[str]


class Mission(_Model):
    """The mission in force: situations, time slots, services and rewards."""

    name: str
    situations: list[str]
    time_slots: list[TimeSlot]
    services: list[MissionService]
    rewards: dict[str, float]
    unavailable_situations: list[str] = Field(default_factory=list)
    gamma: float | None = None


# -- the outbox ----------------------------------------------------------------------------------
class Queued(_Model):
    """A report kept in the outbox because the service could not be reached: it will be
    delivered, in order, when the service answers again.

    ``key`` is the report's ``decision_id`` (outcomes) or ``feedback_id`` (feedback);
    ``position`` is its place in the queue (1 is next).
    """

    kind: ReportKind
    episode_id: str
    key: str
    position: int


class PendingReport(_Model):
    """A report waiting in the outbox (or one that was delivered or rejected, in a
    ``FlushReport``).

    ``seq`` orders the reports (they are delivered by increasing ``seq``); ``body`` is the JSON
    that is sent; ``attempts`` counts the requests that failed to deliver it, the last with
    ``last_error``.
    """

    seq: int
    kind: ReportKind
    episode_id: str
    key: str
    body: dict[str, Any]
    queued_at: dt.datetime
    attempts: int = 0
    last_error: str | None = None


class Rejection(_Model):
    """Why the service refused a queued report for good (its status and error body)."""

    status_code: int
    error: str
    detail: str
    fields: list[dict[str, Any]] | None = None
    request_id: str | None = None
    rejected_at: dt.datetime


class FlushReport(_Model):
    """What delivering the outbox did.

    ``delivered`` pairs each delivered report with the service's answer (for an outcome, the
    next decision of its episode); ``rejected`` pairs each report the service refused for good
    with the reason (it left the queue); ``remaining`` counts the reports still queued.
    """

    delivered: list[tuple[PendingReport, OutcomeResult | FeedbackResult]] = Field(
        default_factory=list)
    rejected: list[tuple[PendingReport, Rejection]] = Field(default_factory=list)
    remaining: int = 0
