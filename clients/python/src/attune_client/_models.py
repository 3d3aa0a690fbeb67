"""Typed views of the API's JSON (pydantic v2).

Every model accepts fields it does not know (the contract lets the service add fields, and an
older client must keep working): they are kept, readable as attributes and in
``model_extra``.

Strings whose values the contract fixes are ``Literal`` types, so that a type checker catches
a misspelt one (``report_outcome(..., response="acepted")`` fails ``mypy --strict``): the kinds
of action (:data:`ActionKind`), the responses (:data:`OutcomeResponse`), feedback
(:data:`Feedback`), the initiator (:data:`Initiator`), the negotiation's states
(:data:`NegotiationState`), an episode's status, a correction's kind, what decided a change
(:data:`ChangeSource`). They are ``Literal`` rather than enums because the JSON holds strings:
a value compares equal to the text the service sends and to the text a robot's code writes,
and nothing is converted on the way.

What each mission defines is plain ``str``: situations, time slots, services and details are
the names of the fleet's mission (``GET /v1/mission``), which staff may change at any time, so
no type can list them.

A kind of action, a response, a state or a change's source that a newer service adds within v1
(changes there only add) still parses: those fields are typed with their ``Literal`` for the
type checker but accept any string at run time, as they always did. ``status`` and the other
enumerations the client checked before are checked as before.
"""

from __future__ import annotations

import datetime as dt
from typing import Annotated, Any, Literal, NotRequired, TypedDict

from pydantic import BaseModel, ConfigDict, Field, PlainValidator

__all__ = [
    "Action",
    "ActionKind",
    "ActionBelief",
    "ActionProbability",
    "ChangeEvent",
    "ChangeEvidence",
    "ChangeList",
    "ChangeMoment",
    "ChangeSource",
    "Context",
    "ContextBelief",
    "Correction",
    "CorrectionKind",
    "CorrectionList",
    "Decision",
    "EpisodePage",
    "EpisodeStarted",
    "EpisodeState",
    "EpisodeSummary",
    "EpisodeTrace",
    "Feedback",
    "FeedbackResult",
    "FleetMission",
    "FleetPrior",
    "FlushReport",
    "Initiator",
    "LearnerSpec",
    "Mission",
    "MissionChanged",
    "MissionRenames",
    "MissionService",
    "MissionVersion",
    "MissionVersionList",
    "ModelView",
    "NegotiationState",
    "Outcome",
    "OutcomeResponse",
    "OutcomeResult",
    "PendingReport",
    "Profile",
    "ProfileChange",
    "ProfileContext",
    "ProfileEvidence",
    "Queued",
    "Rejection",
    "RobotWill",
    "ServiceRequest",
    "StartedFrom",
    "StateBelief",
    "Stats",
    "TimeSlot",
    "TraceDecision",
    "TraceFeedback",
    "User",
    "UserPage",
    "Wanted",
]

EpisodeStatus = Literal["open", "closed", "interrupted"]
"""``interrupted``: the episode was closed by a change of its fleet's mission; it takes no more
outcomes (one gets ``EpisodeInterruptedError``)."""
ReportKind = Literal["outcome", "feedback"]
CorrectionKind = Literal["prefers", "avoid", "quiet"]
"""``prefers`` (a service and detail the robot brings without asking, until the person's own
answers contradict it twice in a row), ``avoid`` (a service, or a service and detail, the robot
never chooses there), ``quiet`` (the robot never initiates there)."""
CorrectionStatus = Literal["in_force", "overridden", "lifted", "idle"]
ChangeSource = Literal["routine", "change_test", "profile"]
"""What decided a change in what a person wants: ``routine`` (``dts-routine``'s routine for the
context was refused and replaced, or given up), ``change_test`` (DTS's change test), or
``profile`` (the person's own answers no longer support what they wanted: every learner without
a mechanism of its own)."""
Certainty = Literal["unknown", "tentative", "confident"]
ActionKind = Literal[
    "initiate",
    "pass",
    "query_type",
    "query_detail",
    "perform",
    "respond",
    "infer_type",
    "infer_detail",
]
"""What the robot must do: ``initiate`` (approach and offer help), ``pass`` (stay passive),
``query_type`` (ask which service), ``query_detail`` (ask which detail of ``service``),
``perform`` (``service`` / ``detail``); and the silent steps the service takes itself, which
appear in a decision's ``chain`` only: ``respond`` (to a request), ``infer_type``,
``infer_detail``."""
OutcomeResponse = Literal["accepted", "rejected", "terminated", "human_request", "none", "answered"]
"""What the person did (one of the decision's ``expects``): ``accepted`` or ``rejected`` (an
offer or a service), ``terminated`` (ended the dialog), ``human_request`` (asked, while the
robot stayed passive), ``none`` (nothing happened), ``answered`` (a question)."""
Feedback = Literal["positive", "negative"]
"""Explicit feedback: a smile, a touch (``positive``), or the opposite."""
Initiator = Literal["robot", "human"]
"""Who began an episode: the robot noticed the person, or the person addressed the robot."""
NegotiationState = Literal["OBSERVE", "REQUEST", "ENGAGED", "TYPE_KNOWN", "DETAIL_KNOWN", "END"]
"""The negotiation's states (docs/method.md §2 of the Attune repository); the service and detail
they concern, where they have one, are fields of their own."""


class Outcome(TypedDict):
    """What the person did, as ``report_outcome(episode_id, decision_id=..., **outcome)``
    takes it: ``response`` always, ``service`` and ``detail`` where the response names them,
    ``feedback`` when the person gave some with it. For a robot's code that works out the
    reaction in one place and reports it in another, typed as the call's arguments are."""

    response: OutcomeResponse
    service: NotRequired[str]
    detail: NotRequired[str]
    feedback: NotRequired[Feedback]


def _text(value: Any) -> str:
    """Any string: what these fields held before they were typed (see the module)."""
    if not isinstance(value, str):
        raise ValueError(f"expected a string, got {type(value).__name__}")
    return value


# Typed with the contract's values for the type checker; any string at run time (the module).
_ActionKind = Annotated[ActionKind, PlainValidator(_text)]
_OutcomeResponse = Annotated[OutcomeResponse, PlainValidator(_text)]
_Feedback = Annotated[Feedback, PlainValidator(_text)]
_State = Annotated[NegotiationState, PlainValidator(_text)]
_ChangeSource = Annotated[ChangeSource, PlainValidator(_text)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="allow", frozen=True)


# -- actions and decisions ---------------------------------------------------------------------
class Action(_Model):
    """An action of the negotiation: ``kind`` (:data:`ActionKind`: ``initiate``, ``pass``,
    ``query_type``, ``query_detail``, ``perform``, or a silent one in ``chain``), with
    ``service`` and ``detail`` (names of the mission) where it has them."""

    kind: _ActionKind
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
    expects: list[_OutcomeResponse]
    probabilities: list[ActionProbability]
    chain: list[ActionProbability] = Field(default_factory=list)


class EpisodeStarted(_Model):
    """The answer to an event: the new episode and the robot's first decision.

    ``replayed`` is True when the service answered a repeated ``event_id`` (nothing changed).
    ``mission_version`` is the fleet's mission version the episode runs under (None in answers
    the service stored before missions had versions).
    """

    episode_id: str
    user_id: str
    status: EpisodeStatus
    context: Context
    state: _State
    total_reward: float
    decision: Decision | None
    mission_version: int | None = None
    replayed: bool = False


class EpisodeState(_Model):
    """An episode's status, state and reward so far."""

    episode_id: str
    status: EpisodeStatus
    state: _State
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
    """A learner: the algorithm (``dts-routine``, ``hri``, ``rmax``...) and its parameters
    (omitted ones keep the service's defaults)."""

    algorithm: str = "dts-routine"
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
    fleet_prior: bool = True


class UserPage(_Model):
    """One page of users; pass ``next_cursor`` back for the next (None on the last page)."""

    items: list[User]
    next_cursor: str | None = None


# -- episodes ------------------------------------------------------------------------------------
class TraceDecision(_Model):
    """One decision of an episode's trace, with the response it got (None while open)."""

    decision_id: str
    state: _State
    action: Action
    probabilities: list[ActionProbability]
    chain: list[ActionProbability] = Field(default_factory=list)
    response: _OutcomeResponse | None = None
    service: str | None = None
    detail: str | None = None
    feedback: _Feedback | None = None
    reward: float | None = None
    decided_at: dt.datetime
    answered_at: dt.datetime | None = None


class TraceFeedback(_Model):
    """One piece of feedback of an episode's trace."""

    feedback_id: str
    feedback: _Feedback
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
    initiator: Initiator
    interaction_class: Literal["I1", "I2", "I3", "none"]
    total_reward: float
    state: _State | None = None
    occurred_at: dt.datetime | None = None
    index: int | None = None
    mission_version: int | None = None


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

    state: _State
    service: str | None = None
    detail: str | None = None
    actions: list[ActionBelief]


class ContextBelief(_Model):
    """The learner's view of one context (time slot and situation)."""

    time_slot: str
    situation: str
    states: list[StateBelief]


class StartedFrom(_Model):
    """What a model grew from: ``kind`` ``fresh``, ``imported`` or ``fleet_prior`` (then
    ``contributors``: how many of the fleet's people the prior averaged)."""

    kind: str = "fresh"
    contributors: int | None = None


class ModelView(_Model):
    """What a user's learner believes now; ``version`` goes up by one with every change."""

    user_id: str
    algorithm: str
    params: dict[str, Any] = Field(default_factory=dict)
    version: int
    episodes: int
    started_from: StartedFrom = Field(default_factory=StartedFrom)
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


# -- the profile and staff corrections ---------------------------------------------------------
class Wanted(_Model):
    """A service, and its detail when known."""

    service: str
    detail: str | None = None


class ProfileEvidence(_Model):
    """What the person did in one context: services taken (``accepted``), offers, services and
    questions turned down (``refused``), requests made (``asked_for``), questions answered
    (``answered``), the latest episode in the person's local time (``last_seen``), and how many
    of their latest answers there (``recent``, up to 8) agree with what they are believed to
    want (``support``)."""

    accepted: int
    refused: int
    asked_for: int
    answered: int
    last_seen: dt.datetime | None = None
    support: int
    recent: int


class RobotWill(_Model):
    """What the robot will most likely do when it meets the person in one context:
    ``offer`` (bringing ``service`` and ``detail``, or asking first when ``asks_first``),
    ``wait_to_be_asked`` or ``stay_away``; ``probability`` is the chance it offers."""

    action: Literal["offer", "wait_to_be_asked", "stay_away"]
    service: str | None = None
    detail: str | None = None
    asks_first: bool
    probability: float


class ProfileChange(_Model):
    """The person's recent answers contradict what they wanted ``before``: since ``episode``
    (the user's episode index; ``at`` in their local time) they want ``now`` (None: they only
    turned things down). ``overrides`` names the ``prefers`` correction their answers
    overrode, if any."""

    at: dt.datetime | None = None
    episode: int
    before: Wanted | None = None
    now: Wanted | None = None
    by: Literal["person"] = "person"
    overrides: str | None = None


class ProfileContext(_Model):
    """What the person is believed to want in one time slot and situation, in plain words
    (``summary``) and in fields: ``wants`` (None: nothing yet), its ``certainty`` and
    ``source`` (``person``: their own answers; ``staff``: a ``prefers`` correction in force)."""

    time_slot: str
    situation: str
    episodes: int
    open_episodes: int
    wants: Wanted | None = None
    certainty: Certainty
    source: Literal["person", "staff"] | None = None
    evidence: ProfileEvidence
    robot_will: RobotWill
    summary: str
    changed: ProfileChange | None = None
    corrections: list[str] = Field(default_factory=list)


class Correction(_Model):
    """A staff correction of what was learned about a user, in one time slot and situation.

    ``status``: ``in_force``, ``overridden`` (the person's own answers contradicted a
    ``prefers``), ``lifted`` (by staff) or ``idle`` (the fleet's mission no longer has its
    names). ``model_version`` is the model version it produced. ``replayed`` is True when the
    service answered a repeated ``correction_id`` (nothing changed).
    """

    correction_id: str
    kind: CorrectionKind
    time_slot: str
    situation: str
    service: str | None = None
    detail: str | None = None
    note: str | None = None
    author: str
    created_at: dt.datetime
    status: CorrectionStatus
    overridden_at: dt.datetime | None = None
    lifted_at: dt.datetime | None = None
    lifted_by: str | None = None
    model_version: int
    replayed: bool = False


class CorrectionList(_Model):
    """Every correction of a user, lifted ones too, oldest first."""

    items: list[Correction]


class Profile(_Model):
    """What Attune believes about a person, one entry per (time slot, situation) of the
    fleet's mission. ``utc_offset`` (minutes east of UTC of the latest event; None: shown in
    UTC) is the local time it speaks in; ``corrections`` are those in force or overridden."""

    user_id: str
    display_name: str | None = None
    episodes: int
    open_episodes: int
    utc_offset: int | None = None
    contexts: list[ProfileContext]
    corrections: list[Correction] = Field(default_factory=list)

    def context(self, time_slot: str, situation: str) -> ProfileContext:
        """The entry of one time slot and situation; ``KeyError`` if the mission has none."""
        for entry in self.contexts:
            if entry.time_slot == time_slot and entry.situation == situation:
                return entry
        raise KeyError(f"no context ({time_slot!r}, {situation!r}) in the profile")


# -- changes told to staff ---------------------------------------------------------------------
class ChangeMoment(_Model):
    """One of the person's episodes (``episode``, their episode index, from 1) and when:
    for a change's ``since``, the episode's time as the robot reported it (its local offset);
    for its ``decided``, when the service decided, in UTC."""

    episode: int
    at: dt.datetime


class ChangeEvidence(_Model):
    """One episode that showed a change: what the person chose (a service, and the detail when
    known; None: nothing), what they turned down, and whether they turned the robot's offer
    of help down."""

    episode: int
    chose: Wanted | None = None
    turned_down: list[Wanted] = Field(default_factory=list)
    turned_down_offer: bool = False


class ChangeEvent(_Model):
    """What a person wants in one time slot and situation changed (a change told to staff).

    ``source`` (:data:`ChangeSource`) says what decided it; ``since`` is the first episode of
    the new wish and ``decided`` the episode whose end decided it (:class:`ChangeMoment`);
    ``before`` is what they wanted before and ``now`` what they want now (None: they turn it
    down and chose nothing else yet); ``evidence`` lists the episodes that showed it, oldest
    first; ``summary`` says it in words for staff. ``change_id`` is opaque.
    """

    change_id: str
    user_id: str
    fleet: str
    source: _ChangeSource
    time_slot: str
    situation: str
    since: ChangeMoment
    decided: ChangeMoment
    before: Wanted | None = None
    now: Wanted | None = None
    evidence: list[ChangeEvidence] = Field(default_factory=list)
    summary: str


class ChangeList(_Model):
    """One page of changes, newest first; pass ``next_cursor`` back for the next (None on the
    last page)."""

    items: list[ChangeEvent]
    next_cursor: str | None = None


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
    """A mission: situations, time slots, services and rewards."""

    name: str
    situations: list[str]
    time_slots: list[TimeSlot]
    services: list[MissionService]
    rewards: dict[str, float]
    unavailable_situations: list[str] = Field(default_factory=list)
    gamma: float | None = None
    labels: dict[str, str] = Field(default_factory=dict)
    """Display only: the words staff read for a name (outside the fingerprint)."""
    time_zone: str = "UTC"
    """Display only: the fleet's IANA time zone, for the console's times."""

    def document(self) -> dict[str, Any]:
        """The mission document alone, as ``set_mission`` takes it and a mission file holds
        it: without ``fleet``, ``version`` and ``fingerprint`` (which say whose it is and
        which version, not what it is)."""
        doc = self.model_dump(mode="json", exclude=set(_PLACE_FIELDS))
        if doc.get("gamma") is None:
            doc.pop("gamma", None)
        if not doc.get("labels"):  # the display fields at their defaults are left out
            doc.pop("labels", None)
        if doc.get("time_zone") == "UTC":
            doc.pop("time_zone", None)
        return doc


_PLACE_FIELDS = ("fleet", "version", "fingerprint")


class FleetMission(Mission):
    """A fleet's mission in force (``GET /v1/mission``), with whose it is and its version.

    ``version`` goes up by one with every change of the fleet's mission; ``fingerprint`` names
    its contents. The three are None from a service older than versioned missions.
    """

    fleet: str | None = None
    version: int | None = None
    fingerprint: str | None = None


class MissionRenames(_Model):
    """What a mission change carries across a rename, old name to new (what was learned under
    the old name is kept under the new). A detail is renamed under every service that has it
    (``{"cha": "tea"}``), or under one (``{"ProvideDrink/cha": "tea"}``)."""

    time_slots: dict[str, str] = Field(default_factory=dict)
    situations: dict[str, str] = Field(default_factory=dict)
    services: dict[str, str] = Field(default_factory=dict)
    details: dict[str, str] = Field(default_factory=dict)


class MissionVersion(_Model):
    """One version of a fleet's mission.

    ``stored`` is False (and ``created_at`` None) for the deployment's default while the fleet
    has no users yet; ``set_by`` is the key that set it (None for the default); ``renames``
    what the change carried across a rename from the previous version.
    """

    version: int
    name: str
    fingerprint: str
    created_at: dt.datetime | None = None
    change_id: str | None = None
    renames: dict[str, Any] | None = None
    set_by: str | None = None
    stored: bool = True
    mission: Mission


class MissionVersionList(_Model):
    """Every version of a fleet's mission, newest first."""

    fleet: str
    current_version: int
    items: list[MissionVersion]


class FleetPrior(_Model):
    """A fleet's prior for newcomers: whether it is on (``enabled``), for which learners it is
    in force now, and how many people can contribute per learner."""

    fleet: str
    enabled: bool
    in_force: list[str] = Field(default_factory=list)
    contributors: dict[str, int] = Field(default_factory=dict)
    min_contributors: int
    min_episodes: int
    max_contributors: int
    strength: float
    mission_version: int
    shared: str = ""
    updated_at: dt.datetime | None = None
    updated_by: str | None = None


class MissionChanged(_Model):
    """The answer to a mission change.

    ``changed`` is False when the mission was already in force (no new version). Otherwise
    ``version`` is the new version, ``users_moved`` counts the models carried to it and
    ``episodes_interrupted`` the open episodes it closed as ``interrupted``; ``diff`` says what
    was kept, added, removed and renamed (None for a fleet's first version). ``replayed`` is
    True when this answers a repeated ``change_id`` (nothing changed now).
    """

    fleet: str
    version: int
    previous_version: int | None = None
    fingerprint: str
    changed: bool
    users_moved: int = 0
    episodes_interrupted: int = 0
    diff: dict[str, Any] | None = None
    replayed: bool = False


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
    """Why the service refused a queued report for good (its status and error body).

    ``interrupted`` is True for an outcome whose episode was interrupted by a change of its
    fleet's mission: it will never be taken (start a new episode for the person).
    """

    status_code: int
    error: str
    detail: str
    fields: list[dict[str, Any]] | None = None
    request_id: str | None = None
    rejected_at: dt.datetime

    @property
    def interrupted(self) -> bool:
        return is_interruption(self.status_code, self.detail)


INTERRUPTED_MARK = "was interrupted when its fleet's mission"


def is_interruption(status_code: int, detail: str) -> bool:
    """True for the service's refusal of an outcome to an episode that a change of its fleet's
    mission interrupted (409, its detail says so)."""
    return status_code == 409 and INTERRUPTED_MARK in detail


class FlushReport(_Model):
    """What delivering the outbox did.

    ``delivered`` pairs each delivered report with the service's answer (for an outcome, the
    next decision of its episode); ``rejected`` pairs each report the service refused for good
    with the reason (it left the queue), and ``interrupted`` lists those of them that were
    outcomes of episodes interrupted by a mission change; ``remaining`` counts the reports
    still queued.
    """

    delivered: list[tuple[PendingReport, OutcomeResult | FeedbackResult]] = Field(
        default_factory=list
    )
    rejected: list[tuple[PendingReport, Rejection]] = Field(default_factory=list)
    remaining: int = 0

    @property
    def interrupted(self) -> list[PendingReport]:
        """The rejected outcomes whose episode a change of its fleet's mission interrupted
        (``Rejection.interrupted``): they left the queue for good; their episodes are over."""
        return [entry for entry, why in self.rejected if why.interrupted]
