"""What another learner would have earned with a fleet's people, read from the fleet's stored logs
(``attune evaluate``; the method: :mod:`app.learning.offpolicy`, docs/method.md §17).

For each person of the fleet (a page of people at a time; each person's rows read in one read
transaction of their own, then worked on with the database let go), the logged history is
rebuilt from what the service stores, and each *candidate* (an algorithm and its parameters,
:class:`CandidateSpec`) is replayed through it, as :func:`app.learning.whatif.replay` does in
simulation:

- **The candidate's start.** The model's journal is walked from the model's base (its
  ``base_version``). A fresh base (a new person, a reset that dropped the corrections) makes a
  fresh candidate. A *stored* base (the fleet's prior, an imported model, a retention run's
  fold, a reset that kept the staff corrections) holds what the logging learner knew there: a
  candidate of the same algorithm starts from it, with its own parameters (a learner's tables do
  not depend on its parameters); a candidate of another algorithm cannot read it and starts
  fresh there, with the base's staff corrections in force. Such a candidate is judged as a
  newcomer from that point, which favours the logger when the base holds much. The history
  before the base (before a reset, an import, or folded by retention) is not evaluated.
- **Teaching.** Every version group of the journal is taught to the candidate with
  :func:`app.services.person_model.apply`, exactly as the person's model was taught: an
  outcome's transitions, explicit feedback, staff corrections and lifts (they bind every
  learner), mission moves (the candidate is carried to the new mission version by names, as the
  model was). A group the candidate refuses (``ValueError``) is left out and counted
  (``entries_refused``).
- **Asking.** A decision row was drawn from the model at its ``model_version``: just before a
  decision, the candidate is taught the journal up to that version and asked, for the states of
  the decision's drawn silent steps and its visible step, the distributions it would have drawn
  from (``distributions``, one plan for the decision, from a generator seeded by the person,
  the candidate and the decision, so that a rerun gives the same numbers) and its Q values
  (``action_values`` undiscounted, in the unit of a return; the doubly robust estimates'
  model). Its probability of the logged action is the *target*; its mass on actions the
  logging distribution gave 0 is *unsupported*.
- **The logged probability** of a step is read from the decision row of the episode and step:
  for the visible step, ``probabilities[action - actions_of(state).start]``; for a silent step,
  the ``p`` its entry of ``chain`` recorded. The service keeps only the drawn action's
  probability of a silent step, so ``unsupported`` is exact at the visible steps and at the
  silent steps drawn with probability 1, and counts nothing at the other silent steps (the
  logging distribution's other actions are not known there). A *forced* step, chosen by the
  person (the robot's passive root of an episode the person began, the response to their
  request, the detail they named), is not the learner's choice under any candidate: it is not
  weighted (logged = target = 1, nothing unsupported; its model terms are 0, which leaves the
  doubly robust estimate's term the step's reward times the weight so far).
- **Rewards.** A step's reward is the decision's (explicit feedback given with the outcome
  included) or the silent step's; explicit feedback given later (``POST .../feedback``) is added
  to the step it was about: the episode's last answered step when it came. An episode's rewards
  sum to its ``total_reward``.
- **Which episodes count.** Episodes *closed* (not open, not interrupted by a mission change)
  whose ``occurred_at`` is in [``since``, ``until``), all of whose decisions were drawn since
  the model's base, under the mission version the model was laid out for. The candidate still
  learns from every earlier part of the history (and from the episodes that do not count).

The episodes of all the people (a person is a cluster) make one
:class:`app.learning.offpolicy.Steps`; per candidate: the estimate (``estimator``, bootstrap
interval over people), the logging learners' own value (``on_policy``: what the robots earn
now), and the *difference* candidate - logged, its interval from the same bootstrap resamples
of people for both (so that what the people have in common cancels); the same per person. A
candidate gets words ("would likely earn more", "less", "about the same") only when the
estimate has the evidence :func:`app.learning.offpolicy.estimate` asks for and an interval no
wider than the range of the logged episodes' returns (:func:`evidence`); else "not enough
evidence", with why. Nothing is written; the same logs give the same numbers.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import hashlib
from collections import OrderedDict
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from app.db.repositories import episodes as episodes_repo
from app.db.repositories import journal
from app.db.repositories import models as models_repo
from app.db.repositories import users as users_repo
from app.db.repositories.episodes import DecisionRow, EpisodeRow
from app.db.repositories.users import UserRow
from app.db.session import Database
from app.errors import NotFound, ValidationFailed
from app.learning import learner_from_state, make_learner
from app.learning.config import PARAMS
from app.learning.guidance import Rule, guidance_from_state
from app.learning.learners import ALGORITHMS, TabularLearner
from app.learning.offpolicy import (
    DEFAULT_CLIP,
    DEFAULT_ESTIMATOR,
    ESTIMATORS,
    MIN_CLUSTERS,
    MODEL_ESTIMATORS,
    Estimate,
    Steps,
    estimate,
    expanded_level,
    on_policy,
    per_cluster,
    resampled,
    unseen_margins,
)
from app.learning.prior import FRESH_ONLY, population_prior
from app.learning.remap import remap_learner
from app.learning.state import StateFormatError
from app.learning.types import FloatArray
from app.schemas.users import LearnerSpec

from .context import ServiceContext
from .mission_book import Stored
from .person_model import PersonModel, apply

__all__ = [
    "CONFIDENCE",
    "N_BOOT",
    "CandidateResult",
    "CandidateSpec",
    "Difference",
    "FleetEvaluation",
    "PersonResult",
    "candidate_spec",
    "evaluate_fleet",
    "evidence",
    "parse_candidate",
    "relearned",
    "shadow_decisions",
    "ShadowDecision",
    "verdict",
]

PEOPLE_PAGE = 100  # people read per transaction while the fleet is listed
EPISODE_PAGE = 1_000  # a person's episodes read at a time
N_BOOT = 1_000  # bootstrap resamples of every interval
CONFIDENCE = 0.95
_BLOCK = 1 << 21  # the difference's bootstrap draws its count matrix in blocks of this many
_TOLERANCE = 1e-6  # rewards that sum to an episode's total_reward up to this (absolute)

_NAMES: Mapping[str, str] = {
    "hri": "HRI",
    "rmax": "R-MAX",
    "qlearning": "Q-learning",
    "dts": "DTS",
    "dts-adapt": "DTS-adapt",
    "dts-routine": "DTS-routine",
}
_SYMBOLS: Mapping[str, str] = {"tau": "τ"}
_TRUE = frozenset({"true", "yes", "on", "1"})
_FALSE = frozenset({"false", "no", "off", "0"})
_EXAMPLES = (
    "hri, hri:tau=0.005, dts-routine:samples=32,ask_unknown=false, default, dts:prior=off, "
    "current:prior=on"
)
PRIOR = "prior"
"""The name ``parse_candidate`` reads a candidate's ``fleet_prior`` under (on or off)."""
DEFAULT = "default"
CURRENT = "current"
"""A candidate's algorithm that names each person's own learner, as it is (with ``fleet_prior``
set: the question is then only where they start)."""
DEFAULT_ALGORITHM = LearnerSpec.model_fields["algorithm"].default
"""The learner a person gets when nobody chooses one: what ``default`` names."""


# ---------------------------------------------------------------------------------------------
# Candidates


@dataclass(frozen=True)
class CandidateSpec:
    """A learner to evaluate: ``algorithm`` with ``params`` (the ones given; the others keep
    their defaults). Made by :func:`candidate_spec` or :func:`parse_candidate`, which validate
    both as the API validates a person's learner."""

    algorithm: str
    params: Mapping[str, Any] = field(default_factory=dict)
    fleet_prior: bool | None = None
    """Where each person's candidate starts: ``True``, from the fleet's prior (those who started
    fresh are given the prior the fleet's other people make today); ``False``, fresh (those who
    started from the prior start without it); ``None``, where the person's model started."""

    @property
    def full_params(self) -> dict[str, Any]:
        """Every parameter, the defaults filled in."""
        return PARAMS[self.algorithm].from_dict(dict(self.params)).to_dict()

    @property
    def key(self) -> str:
        """The candidate as ``parse_candidate`` reads it: ``hri:tau=0.005``,
        ``current:prior=off``."""
        given = {k: _text(v) for k, v in self.params.items()}
        if self.fleet_prior is not None:
            given[PRIOR] = "on" if self.fleet_prior else "off"
        if not given:
            return self.algorithm
        return f"{self.algorithm}:" + ",".join(f"{k}={v}" for k, v in sorted(given.items()))

    @property
    def label(self) -> str:
        """For people: ``HRI τ=0.005``, ``The current learners, without the fleet's prior``."""
        if self.algorithm == CURRENT:
            name = "The current learners"
        else:
            name = _NAMES.get(self.algorithm, self.algorithm)
        given = " ".join(f"{_SYMBOLS.get(k, k)}={_text(v)}" for k, v in sorted(self.params.items()))
        text = f"{name} {given}" if given else name
        if self.fleet_prior is None:
            return text
        return f"{text}, {'with' if self.fleet_prior else 'without'} the fleet's prior"

    def for_person(self, user: UserRow) -> CandidateSpec:
        """The candidate for one person: ``current`` becomes their own learner."""
        if self.algorithm != CURRENT:
            return self
        return CandidateSpec(user.algorithm, dict(user.params), self.fleet_prior)

    def to_dict(self) -> dict[str, Any]:
        return {
            "key": self.key,
            "label": self.label,
            "algorithm": self.algorithm,
            "params": dict(self.params),
            "fleet_prior": self.fleet_prior,
        }


def _text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return f"{value:g}" if isinstance(value, float) else str(value)


def candidate_spec(
    algorithm: str, params: Mapping[str, Any] | None = None, fleet_prior: bool | None = None
) -> CandidateSpec:
    """A validated candidate: ``ValueError`` with the sentence the API gives for a person's
    learner (an unknown algorithm, an unknown or bad parameter). ``default`` names the learner
    a person gets when nobody chooses one (``DEFAULT_ALGORITHM``); ``current`` each person's
    own learner, with ``fleet_prior`` true or false (where they start is then the question)."""
    if algorithm == DEFAULT:
        algorithm = DEFAULT_ALGORITHM
    if fleet_prior is not None and not isinstance(fleet_prior, bool):
        raise ValueError(f"fleet_prior must be true, false or left out; got {fleet_prior!r}.")
    if algorithm == CURRENT:
        if params:
            raise ValueError("current takes no parameters: it is each person's own learner.")
        if fleet_prior is None:
            raise ValueError(
                "current needs fleet_prior true or false (prior=on or prior=off): the current "
                "learners as they started are what the robots earn now."
            )
        return CandidateSpec(CURRENT, {}, fleet_prior)
    if not isinstance(algorithm, str) or algorithm not in ALGORITHMS:
        raise ValueError(
            f"algorithm must be one of {', '.join(sorted(ALGORITHMS))}; got {algorithm!r}."
        )
    if fleet_prior and algorithm in FRESH_ONLY:
        raise ValueError(
            f"{_NAMES.get(algorithm, algorithm)} always starts fresh: it cannot start from the "
            "fleet's prior."
        )
    given = dict(params or {})
    checked = PARAMS[algorithm].from_dict(given)  # ValueError naming the parameter
    return CandidateSpec(algorithm, {k: getattr(checked, k) for k in given}, fleet_prior)


def live_candidate(algorithm: str, params: Mapping[str, Any] | None) -> CandidateSpec:
    """The candidate of a shadow or a rollout (``body.candidate``): a learner the robots could
    use, so not ``current``; :class:`ValidationFailed` (422) says what is wrong."""
    try:
        if algorithm == CURRENT:
            raise ValueError(
                "current names the learners the robots use now: a shadow or a rollout tries "
                "another learner."
            )
        return candidate_spec(algorithm, params)
    except ValueError as exc:
        raise ValidationFailed(
            f"candidate: {exc}", fields=[{"loc": ["body", "candidate"], "msg": str(exc)}]
        ) from None


def parse_candidate(text: str) -> CandidateSpec:
    """``ALGORITHM[:NAME=VALUE[,NAME=VALUE...]]`` (``dts``, ``hri:tau=0.005``,
    ``dts-routine:samples=32,ask_unknown=false``) as a validated :class:`CandidateSpec`;
    ``ValueError`` with a sentence naming what is wrong."""
    spelled = text.strip()
    algorithm, colon, rest = spelled.partition(":")
    algorithm = algorithm.strip()
    try:
        if not algorithm:
            raise ValueError(f"it names no algorithm (for example {_EXAMPLES}).")
        if algorithm == DEFAULT:
            algorithm = DEFAULT_ALGORITHM
        if algorithm not in ALGORITHMS and algorithm != CURRENT:
            raise ValueError(
                f"the algorithm must be one of {', '.join(sorted(ALGORITHMS))} (or default, or "
                f"current); got {algorithm!r}."
            )
        params: dict[str, Any] = {}
        fleet_prior: bool | None = None
        if colon:
            if not rest.strip():
                raise ValueError("no parameters after ':' (NAME=VALUE, separated by commas).")
            types = (
                {f.name: str(f.type) for f in dataclasses.fields(PARAMS[algorithm])}
                if algorithm in PARAMS
                else {}
            )
            for item in rest.split(","):
                name, equals, value = (part.strip() for part in item.partition("="))
                if not equals or not name or not value:
                    raise ValueError(
                        f"{item.strip()!r} is not NAME=VALUE (parameters are NAME=VALUE, "
                        "separated by commas)."
                    )
                if name in params or (name == PRIOR and fleet_prior is not None):
                    raise ValueError(f"{name} is given twice.")
                if name == PRIOR:
                    fleet_prior = _value(name, value, "bool")
                    continue
                params[name] = _value(name, value, types.get(name))
        return candidate_spec(algorithm, params, fleet_prior)
    except ValueError as exc:
        raise ValueError(f"candidate {text!r}: {exc}") from None


def _value(name: str, value: str, kind: str | None) -> Any:
    """A parameter's value from its text, by the parameter's type (an unknown parameter keeps
    its text: the parameters' own check names it)."""
    if kind == "bool":
        if value.lower() in _TRUE:
            return True
        if value.lower() in _FALSE:
            return False
        raise ValueError(f"{name} must be true or false, got {value!r}.")
    if kind == "int":
        try:
            return int(value)
        except ValueError:
            raise ValueError(f"{name} must be a whole number, got {value!r}.") from None
    if kind == "float":
        try:
            return float(value)
        except ValueError:
            raise ValueError(f"{name} must be a number, got {value!r}.") from None
    return value


# ---------------------------------------------------------------------------------------------
# Results


@dataclass(frozen=True)
class Difference:
    """Candidate minus the logging learners, per encounter: ``value`` and its ``confidence``
    interval, from the same bootstrap resamples for both (``method`` as an
    :class:`app.learning.offpolicy.Interval`'s)."""

    value: float
    low: float
    high: float
    method: str
    confidence: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "value": self.value,
            "low": self.low,
            "high": self.high,
            "method": self.method,
            "confidence": self.confidence,
        }


@dataclass(frozen=True)
class CandidateResult:
    """One candidate over the fleet: its estimate, the difference with what the robots earn
    now (None without enough evidence), why there is not enough evidence ("" when there is:
    :func:`evidence`), the words for it, and how many journal groups it refused."""

    spec: CandidateSpec
    estimate: Estimate
    difference: Difference | None
    reason: str
    verdict: str
    entries_refused: int = 0

    @property
    def enough(self) -> bool:
        return not self.reason and self.difference is not None

    def to_dict(self) -> dict[str, Any]:
        return {
            **self.spec.to_dict(),
            "enough": self.enough,
            "reason": self.reason,
            "estimate": self.estimate.to_dict(),
            "difference": None if self.difference is None else self.difference.to_dict(),
            "verdict": self.verdict,
            "entries_refused": self.entries_refused,
        }


@dataclass(frozen=True)
class PersonResult:
    """One person's episodes counted, the logging learner's value for them and each
    candidate's estimate from their episodes alone (in the order of the candidates)."""

    user_id: str
    algorithm: str
    episodes: int
    mean_return: float  # the mean total reward of their episodes counted
    logged: Estimate
    candidates: tuple[Estimate, ...]

    def to_dict(self, specs: Sequence[CandidateSpec]) -> dict[str, Any]:
        return {
            "user_id": self.user_id,
            "algorithm": self.algorithm,
            "episodes": self.episodes,
            "mean_return": self.mean_return,
            "logged": self.logged.to_dict(),
            "candidates": {
                spec.key: e.to_dict() for spec, e in zip(specs, self.candidates, strict=True)
            },
        }


@dataclass(frozen=True)
class FleetEvaluation:
    """What ``evaluate_fleet`` found: the logging learners' value (``logged``), each
    candidate's, and per person; what was counted and what was not (``skipped``: episodes by
    reason; ``people_skipped``: people whose history could not be replayed, with why)."""

    fleet: str
    since: dt.datetime | None
    until: dt.datetime | None
    estimator: str
    people: int
    people_counted: int
    episodes: int
    learners: dict[str, int]  # the fleet's people per algorithm (the logging learners)
    logged: Estimate
    candidates: tuple[CandidateResult, ...]
    persons: tuple[PersonResult, ...]
    skipped: dict[str, int]
    people_skipped: tuple[tuple[str, str], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        specs = [c.spec for c in self.candidates]
        return {
            "fleet": self.fleet,
            "since": None if self.since is None else self.since.isoformat(),
            "until": None if self.until is None else self.until.isoformat(),
            "estimator": self.estimator,
            "confidence": CONFIDENCE,
            "people": self.people,
            "people_counted": self.people_counted,
            "episodes": self.episodes,
            "learners": dict(self.learners),
            "logged": self.logged.to_dict(),
            "candidates": [c.to_dict() for c in self.candidates],
            "persons": [p.to_dict(specs) for p in self.persons],
            "skipped": dict(self.skipped),
            "people_skipped": [{"user_id": u, "reason": r} for u, r in self.people_skipped],
        }


def _signed(value: float) -> str:
    shown = round(value, 2) + 0.0  # -0.004 shows as +0.00, not −0.00
    return f"{shown:+.2f}".replace("-", "−")


def evidence(estimate: Estimate, observed: tuple[float, float] | None) -> str:
    """Why ``estimate`` says nothing ("" when it says something): the estimate's own reason
    (too few episodes, too small an effective size, weights that rarely show the candidate), or
    an interval wider than the whole range of the logged episodes' returns (``observed``): such
    an interval cannot place the candidate anywhere within what the robots were seen to earn
    (a candidate whose model is far off makes the doubly robust estimate that noisy)."""
    if not estimate.enough:
        return estimate.reason
    interval = estimate.interval
    if interval is None or observed is None:
        return ""
    lowest, highest = observed
    if interval.high - interval.low > (highest - lowest) + 1e-9:
        return (
            f"not enough evidence: its interval ({_signed(interval.low)} to "
            f"{_signed(interval.high)}) is wider than the range of the logged episodes' "
            f"returns ({_signed(lowest)} to {_signed(highest)})"
        )
    return ""


def verdict(label: str, difference: Difference | None, reason: str = "") -> str:
    """A candidate's estimate in words, against what the robots earn now (the logging
    learners): ``reason`` when it says nothing (:func:`evidence`)."""
    if reason:
        return reason
    if difference is None:  # the logging learners' value itself lacks evidence
        return "not enough evidence: too few episodes to tell what the robots earn now"
    span = (
        f"{_signed(difference.value)} per encounter, between {_signed(difference.low)} and "
        f"{_signed(difference.high)}"
    )
    if difference.low > 0.0:
        return f"{label} would likely earn more than what the robots do now: {span}"
    if difference.high < 0.0:
        return f"{label} would likely earn less than what the robots do now: {span}"
    return f"{label} would earn about the same as what the robots do now: {span}"


# ---------------------------------------------------------------------------------------------
# A person's history, as read


@dataclass(frozen=True, slots=True)
class _Asked:
    """One decision the candidates are asked about: its drawn steps' states and actions, the
    rows of the person's steps they fill, and the logging distribution of each (None: only the
    drawn action's probability was kept)."""

    model_version: int
    context: int
    episode: int  # the learner's episode index
    position: int
    states: tuple[int, ...]
    actions: tuple[int, ...]
    rows: tuple[int, ...]
    theirs: tuple[FloatArray | None, ...]
    decision_id: str = ""
    decided_at: dt.datetime | None = None
    visible: bool = False  # its last state is the decision's own, the learner's choice


@dataclass
class _History:
    """What a person's replay needs, read in one transaction."""

    user_id: str
    algorithm: str
    base_doc: dict[str, Any] | None
    base_layout: int
    layouts: dict[int, Stored]
    groups: list[list[journal.Entry]]
    rules: dict[int, Rule]
    asked: list[_Asked]
    lengths: list[int]  # of the episodes counted, in the order of their steps
    logged: list[float]
    reward: list[float]
    skipped: dict[str, int] = field(default_factory=dict)  # episodes not counted, by reason
    base_version: int = 0  # the model version of the person's base
    base_origin: str = "fresh"  # where the base came from (fresh, imported, fleet_prior)
    takes_part: bool = True  # the person's fleet_prior: false keeps them from the prior
    priors: dict[str, TabularLearner[Any] | None] = field(default_factory=dict)
    # by candidate key: the fleet's prior such a candidate starts this person from, when it does


def _aware(at: dt.datetime | None) -> dt.datetime | None:
    if at is None or at.tzinfo is not None:
        return at
    return at.replace(tzinfo=dt.UTC)


def _utc(at: dt.datetime) -> dt.datetime:
    return at if at.tzinfo is not None else at.replace(tzinfo=dt.UTC)


def _layout_at(moves: Sequence[tuple[int, int]], base_layout: int, version: int) -> int:
    """The mission version the model was laid out for at model ``version``."""
    layout = base_layout
    for at, to in moves:
        if at > version:
            break
        layout = to
    return layout


def _read_person(
    session: Session,
    ctx: ServiceContext,
    user: UserRow,
    since: dt.datetime | None,
    until: dt.datetime | None,
) -> _History:
    """The person's history since their model's base, and their episodes that count (the
    others counted by reason in ``skipped``)."""
    model = PersonModel.open(session, ctx, user)
    head = model.head
    history, moves = _history_of(session, ctx, user, model, None, head.base_mission_version)
    episodes: list[EpisodeRow] = []
    before: int | None = None
    while True:
        page = episodes_repo.list_page(session, user.id, before_seq=before, limit=EPISODE_PAGE)
        episodes.extend(page)
        if len(page) < EPISODE_PAGE:
            break
        before = page[-1].seq
    episodes.sort(key=lambda e: e.seq)
    drawn = episodes_repo.decisions_for_rebuild(session, user.id, head.base_version)
    _ask(session, history, episodes, drawn, moves, since, until, whole=False)
    return history


def _read_since(
    session: Session, ctx: ServiceContext, user: UserRow, resume: _Resume
) -> _History | None:
    """What a candidate taught up to version ``resume.applied`` still needs of the person's
    history: the journal's version groups after it, and the episodes of the decisions drawn
    from it on (all of theirs): read in a few small queries, whatever the history's length.
    None when that is not the whole of what is new (the model's base moved, or an episode was
    partly drawn before that version): then the history is read whole."""
    model = PersonModel.open(session, ctx, user)
    head = model.head
    if (head.base_version, head.base_mission_version) != resume.base:
        return None
    history, moves = _history_of(
        session, ctx, user, model, resume.applied, resume.layout, base=False
    )
    drawn = episodes_repo.decisions_for_rebuild(session, user.id, max(resume.applied, 0))
    episodes = []
    for episode_id in dict.fromkeys(d.episode_id for d, _, _ in drawn):
        episode = episodes_repo.get(session, episode_id)
        if episode is None:
            return None
        episodes.append(episode)
    episodes.sort(key=lambda e: e.seq)
    if not _ask(session, history, episodes, drawn, moves, None, None, whole=True):
        return None
    return history


def _history_of(
    session: Session,
    ctx: ServiceContext,
    user: UserRow,
    model: PersonModel,
    after: int | None,
    layout: int,
    *,
    base: bool = True,
) -> tuple[_History, list[tuple[int, int]]]:
    """The person's journal groups (since the base, or after version ``after``), their rules,
    the missions they were laid out for, and the mission moves among them, starting from the
    mission version ``layout``; with the base's document unless ``base`` is False (a replay
    that resumes a candidate does not start one)."""
    head = model.head
    layouts = {
        v: ctx.missions.get(session, user.fleet, v)
        for v in range(head.base_mission_version, head.mission_version + 1)
    }
    groups = list(model.history(after))
    rules: dict[int, Rule] = {}
    moves: list[tuple[int, int]] = []
    for g in groups:
        first = g[0]
        if isinstance(first, journal.Correction | journal.Lift):
            rules[first.version] = model.rules(first)
        elif isinstance(first, journal.MissionMove):
            moves.append((first.version, first.mission_version))
    history = _History(
        user_id=user.user_id,
        algorithm=user.algorithm,
        base_doc=model.base_document() if base else None,
        base_layout=layout,
        layouts=layouts,
        groups=groups,
        rules=rules,
        asked=[],
        lengths=[],
        logged=[],
        reward=[],
        base_version=head.base_version,
        base_origin=models_repo.origin(session, user.id).kind if base else "",
        takes_part=user.fleet_prior,
    )
    return history, moves


def _ask(
    session: Session,
    history: _History,
    episodes: list[EpisodeRow],
    drawn: list[tuple[DecisionRow, int, int]],
    moves: list[tuple[int, int]],
    since: dt.datetime | None,
    until: dt.datetime | None,
    *,
    whole: bool,
) -> bool:
    """Fill ``history`` with the episodes that count (in ``episodes``, with their ``drawn``
    decisions) and what is asked at their decisions, in the order the decisions were drawn;
    the others counted by reason. ``whole``: False (and nothing filled) when a closed episode
    lacks some of its decisions among ``drawn``."""
    skipped = history.skipped
    by_episode: dict[str, list[DecisionRow]] = {}
    for decision, _, _ in drawn:
        by_episode.setdefault(decision.episode_id, []).append(decision)

    asked_of: dict[str, _Asked] = {}
    for episode in episodes:
        if episode.status != "closed":
            reason = "open" if episode.status == "open" else "interrupted"
            skipped[reason] = skipped.get(reason, 0) + 1
            continue
        at = _utc(episode.occurred_at)
        if (since is not None and at < since) or (until is not None and at >= until):
            skipped["outside the window"] = skipped.get("outside the window", 0) + 1
            continue
        decisions = sorted(by_episode.get(episode.id, []), key=lambda d: d.position)
        if [d.position for d in decisions] != list(range(len(decisions))) or not decisions:
            if whole:
                return False
            skipped["before the model's base"] = skipped.get("before the model's base", 0) + 1
            continue
        if any(
            _layout_at(moves, history.base_layout, d.model_version) != episode.mission_version
            for d in decisions
        ) or not all(d.reward is not None for d in decisions):
            skipped["unusable"] = skipped.get("unusable", 0) + 1
            continue
        made = _episode_steps(session, history, episode, decisions)
        if made is None:
            skipped["unusable"] = skipped.get("unusable", 0) + 1
            continue
        asked_of.update(made)
    # In the order the decisions were drawn (the models' versions go up in it).
    history.asked = [asked_of[d.id] for d, _, _ in drawn if d.id in asked_of]
    return True


def _episode_steps(
    session: Session, history: _History, episode: EpisodeRow, decisions: list[DecisionRow]
) -> dict[str, _Asked] | None:
    """Append one episode's steps to the person's (logged probability, reward), and return the
    decisions its candidates are asked about; None (nothing appended) when a stored
    probability cannot be a drawn action's."""
    space = history.layouts[episode.mission_version].space
    start = len(history.logged)
    logged: list[float] = []
    reward: list[float] = []
    visible_row: dict[str, int] = {}
    asked: dict[str, _Asked] = {}
    for d in decisions:
        states: list[int] = []
        actions: list[int] = []
        rows: list[int] = []
        theirs: list[FloatArray | None] = []
        for step in d.chain:
            forced = bool(step.get("forced"))
            p = 1.0 if forced else float(step["p"])
            if not forced:
                states.append(int(step["state"]))
                actions.append(int(step["action"]))
                rows.append(start + len(logged))
                theirs.append(None)
            logged.append(p)
            reward.append(float(step["reward"]))
        actions_of = space.actions_of(d.state)
        distribution = np.asarray(d.probabilities, dtype=np.float64)
        if distribution.shape != (len(actions_of),) or d.action not in actions_of:
            return None
        p = 1.0 if d.forced else float(distribution[d.action - actions_of.start])
        if not d.forced:
            states.append(d.state)
            actions.append(d.action)
            rows.append(start + len(logged))
            theirs.append(distribution)
        visible_row[d.id] = len(logged)
        logged.append(p)
        assert d.reward is not None
        reward.append(float(d.reward))
        if states:
            asked[d.id] = _Asked(
                model_version=d.model_version,
                context=episode.context,
                episode=episode.learner_episode,
                position=d.position,
                states=tuple(states),
                actions=tuple(actions),
                rows=tuple(rows),
                theirs=tuple(theirs),
                decision_id=d.id,
                decided_at=d.decided_at,
                visible=not d.forced,
            )
    if any(not 0.0 < p <= 1.0 + _TOLERANCE for p in logged):
        return None
    logged = [min(p, 1.0) for p in logged]
    scale = max(1.0, abs(episode.total_reward))
    if abs(sum(reward) - episode.total_reward) > _TOLERANCE * scale:
        # Explicit feedback given after an outcome: on the last step answered when it came.
        answered = [(_utc(d.answered_at), d) for d in decisions if d.answered_at is not None]
        for fb in episodes_repo.feedback_list(session, episode.id):
            came = _utc(fb.received_at)
            earlier = [d for at, d in answered if at <= came]
            about = (earlier or [d for _, d in answered] or decisions)[-1]
            reward[visible_row[about.id]] += float(fb.reward)
    history.logged.extend(logged)
    history.reward.extend(reward)
    history.lengths.append(len(logged))
    return asked


# ---------------------------------------------------------------------------------------------
# A candidate through a person's history


@dataclass
class _Replayed:
    target: FloatArray
    unsupported: FloatArray
    q_hat: FloatArray
    v_hat: FloatArray
    refused: int = 0


def _seed(fleet: str, user_id: str, spec: CandidateSpec) -> list[int]:
    digest = hashlib.sha256(f"{fleet}\x00{user_id}\x00{spec.key}".encode()).digest()
    return [int(w) for w in np.frombuffer(digest[:16], dtype="<u4")]


def _wants_prior(spec: CandidateSpec, history: _History) -> bool:
    """Whether ``spec`` starts this person from a prior built for it: it asks for the fleet's
    prior, and the person started fresh, or from a prior of another algorithm."""
    if not spec.fleet_prior:
        return False
    doc = history.base_doc
    return doc is None or (
        history.base_origin == "fleet_prior" and doc.get("algorithm") != spec.algorithm
    )


def _start(spec: CandidateSpec, history: _History) -> TabularLearner[Any]:
    """The candidate at the model's base (see the module's docstring)."""
    mission = history.layouts[history.base_layout].mission
    doc = history.base_doc
    if spec.fleet_prior is False and history.base_origin == "fleet_prior":
        return make_learner(spec.algorithm, dict(spec.params), mission)  # a prior holds no rules
    if _wants_prior(spec, history):
        prior = history.priors.get(spec.key)
        if prior is not None:
            return prior
    if doc is not None and doc.get("algorithm") == spec.algorithm:
        try:
            return learner_from_state({**doc, "params": spec.full_params}, mission)
        except StateFormatError:
            pass
    learner = make_learner(spec.algorithm, dict(spec.params), mission)
    if doc is not None:  # staff corrections bind every learner
        learner.guidance = guidance_from_state(doc.get("guidance"))
    return learner


@dataclass
class _Resume:
    """A candidate as a replay of one person left it: taught every version group of their
    journal up to ``applied``, laid out for mission version ``layout``; ``base``: the person's
    model base it started from (their base version and its mission version)."""

    base: tuple[int, int]
    learner: TabularLearner[Any]
    layout: int
    applied: int


class ReplayCache:
    """Candidates left as their last replay left them, by a key of the caller's (the shadow
    and the person): a later replay of the same person teaches only the version groups written
    since, instead of their whole journal again. An entry whose person's model base moved (a
    compaction or a rebuild) is not used. At most ``size`` entries, the least recently used
    dropped first. One thread's: the shadows' pass process keeps one between its passes."""

    def __init__(self, size: int = 2_000) -> None:
        self.size = size
        self._items: OrderedDict[Any, _Resume] = OrderedDict()
        self.hits = 0
        self.misses = 0
        self.rereads = 0  # hits whose new part could not be read alone: read whole

    def __len__(self) -> int:
        return len(self._items)

    def get(self, key: Any, base: tuple[int, int] | None = None) -> _Resume | None:
        """The entry of ``key`` (None when there is none, or when ``base`` is given and the
        entry started from another)."""
        item = self._items.get(key)
        if item is None or (base is not None and item.base != base):
            self.misses += 1
            return None
        self._items.move_to_end(key)
        self.hits += 1
        return item

    def put(self, key: Any, item: _Resume) -> None:
        self._items[key] = item
        self._items.move_to_end(key)
        while len(self._items) > self.size:
            self._items.popitem(last=False)

    def drop(self, where: Callable[[Any], bool]) -> None:
        """Forget the entries whose key ``where`` says (a shadow that stopped)."""
        for key in [k for k in self._items if where(k)]:
            del self._items[key]


def _replay(
    fleet: str,
    history: _History,
    spec: CandidateSpec,
    on_asked: Callable[[_Asked, list[FloatArray], Any], None] | None = None,
    *,
    model: bool = True,
    resume: _Resume | None = None,
) -> _Replayed:
    """The candidate replayed through the person's history: taught each version group of
    their journal in order, asked at each decision of ``history.asked`` once it knows what the
    robot's learner knew then. From ``resume`` (taught up to its ``applied`` version) when
    given, which it leaves as the replay ends."""
    n = len(history.logged)
    out = _Replayed(
        target=np.ones(n), unsupported=np.zeros(n), q_hat=np.zeros(n), v_hat=np.zeros(n)
    )
    if resume is not None:
        learner, layout, applied = resume.learner, resume.layout, resume.applied
    else:
        learner, layout, applied = _start(spec, history), history.base_layout, -1
    layouts, rules = history.layouts, history.rules

    def move(current: TabularLearner[Any], old: int, new: int) -> TabularLearner[Any]:
        for version in range(old + 1, new + 1):
            current = remap_learner(current, layouts[version].mission, layouts[version].renames)
        return current

    def rule(entry: journal.Correction | journal.Lift) -> Rule:
        return rules[entry.version]

    seed = _seed(fleet, history.user_id, spec)
    logged = history.logged
    groups = iter([g for g in history.groups if g[0].version > applied])
    pending = next(groups, None)
    for asked in history.asked:
        while pending is not None and pending[0].version <= asked.model_version:
            try:
                learner, layout = apply(learner, pending, layout=layout, rules=rule, move=move)
            except (ValueError, KeyError):
                out.refused += 1
            applied = pending[0].version
            pending = next(groups, None)
        rng = np.random.default_rng([*seed, asked.episode, asked.position])
        mine = learner.distributions(asked.context, asked.states, asked.episode, rng)
        if on_asked is not None:
            on_asked(asked, mine, learner.space)
        # The candidate's Q values: the doubly robust estimate's model (``model``), left at 0
        # for the estimators that do not use them.
        q = learner.action_values(asked.context, gamma=1.0) if model else None
        space = learner.space
        for state, action, row, ours, theirs in zip(
            asked.states, asked.actions, asked.rows, mine, asked.theirs, strict=True
        ):
            actions = space.actions_of(state)
            out.target[row] = min(1.0, max(0.0, float(ours[action - actions.start])))
            if q is not None:
                out.q_hat[row] = float(q[action])
                out.v_hat[row] = float(ours @ q[actions.start : actions.stop])
            if theirs is not None:
                out.unsupported[row] = min(1.0 - out.target[row], float(ours[theirs <= 0.0].sum()))
            elif logged[row] >= 1.0:  # a silent step the logger was sure of: nothing else
                out.unsupported[row] = 1.0 - out.target[row]
    if resume is not None:
        resume.learner, resume.layout, resume.applied = learner, layout, applied
    return out


@dataclass(frozen=True)
class ShadowDecision:
    """What a candidate would have decided at one of the person's decisions: its distribution
    over the decision's actions (``probabilities``, in the order of the state's actions), the
    action it draws from it (``action``), and its probability of the robot's action
    (``logged_probability``)."""

    decision_id: str
    decided_at: dt.datetime
    state: int
    action: int
    probabilities: list[float]
    logged_action: int
    logged_probability: float

    @property
    def agrees(self) -> bool:
        return self.action == self.logged_action


def shadow_decisions(
    session: Session,
    ctx: ServiceContext,
    user: UserRow,
    spec: CandidateSpec,
    *,
    since: dt.datetime,
    done: set[str] | Callable[[list[str]], set[str]],
    cache: ReplayCache | None = None,
    key: Any = None,
) -> list[ShadowDecision]:
    """The candidate's decisions at the person's decisions drawn at or after ``since`` (and not
    in ``done``) of their closed episodes: the candidate replayed through their history as the
    evaluation replays it (so it knows what the robot's learner knew at each), asked at each
    decision the robot's learner chose (the forced ones are the person's). Its action is drawn
    from a generator seeded by the person, the candidate and the decision: the same logs give
    the same decisions.

    With ``cache``, the candidate is taken up where the last replay of ``key`` (the shadow and
    the person) left it, and left there for the next: taught only the version groups written
    since, the same candidate as a replay from the base (what it is taught does not depend on
    what it was asked), at a cost that does not grow with the person's history."""
    found: list[ShadowDecision] = []
    seed = _seed(user.fleet, user.user_id, spec)

    def asked_at(asked: _Asked, mine: list[FloatArray], space: Any) -> None:
        at = asked.decided_at
        if not asked.visible or at is None or asked.decision_id in stored or _utc(at) < since:
            return
        ours = np.asarray(mine[-1], dtype=np.float64)
        state, logged = asked.states[-1], asked.actions[-1]
        first = space.actions_of(state).start
        rng = np.random.default_rng([*seed, 0x5AD0, asked.episode, asked.position])
        total = float(ours.sum())
        weights = ours / total if total > 0 else np.full(ours.shape, 1.0 / ours.size)
        drawn = first + int(rng.choice(ours.size, p=weights))
        found.append(
            ShadowDecision(
                decision_id=asked.decision_id,
                decided_at=_utc(at),
                state=state,
                action=drawn,
                probabilities=[float(p) for p in ours],
                logged_action=logged,
                logged_probability=float(ours[logged - first]),
            )
        )

    stored: set[str] = set()

    def still_to_ask(history: _History) -> list[_Asked]:
        # Only the decisions still to shadow are asked about: the candidate is still taught
        # the whole history in order, but asks nothing at the older decisions.
        wanted = [
            a
            for a in history.asked
            if a.visible and a.decided_at is not None and _utc(a.decided_at) >= since
        ]
        stored.clear()
        stored.update(done if isinstance(done, set) else done([a.decision_id for a in wanted]))
        return [a for a in wanted if a.decision_id not in stored]

    resume = None if cache is None else cache.get(key)  # its base is checked as it is read
    history = None if resume is None else _read_since(session, ctx, user, resume)
    if history is not None and resume is not None:
        history.asked = still_to_ask(history)
        if history.asked and resume.applied > min(a.model_version for a in history.asked):
            history = None  # taught past a decision still to shadow (its store failed)
    if history is None and resume is not None and cache is not None:
        cache.rereads += 1
    if history is None:
        resume = None
        history = _read_person(session, ctx, user, None, None)
        history.asked = still_to_ask(history)
    if not history.asked:
        return found
    if cache is not None and resume is None:
        base = (history.base_version, history.base_layout)
        resume = _Resume(base, _start(spec, history), history.base_layout, -1)
    try:
        _replay(user.fleet, history, spec, on_asked=asked_at, model=False, resume=resume)
    except BaseException:
        if cache is not None:
            cache.drop(lambda k: k == key)  # half taught
        raise
    if cache is not None and resume is not None:
        cache.put(key, resume)
    return found


def relearned(
    session: Session, ctx: ServiceContext, user: UserRow, spec: CandidateSpec
) -> tuple[TabularLearner[Any], int]:
    """The learner ``spec`` as it would be now had it served the person from their model's
    base: started as a candidate starts (:func:`_start`), then taught every version group of
    the person's journal in order, as the evaluation's replay teaches it; with the number of
    groups it refused. A rollout moves a person between learners with it, so that what was
    learned about them is learned again by the learner they move to, not forgotten."""
    model = PersonModel.open(session, ctx, user)
    head = model.head
    layouts = {
        v: ctx.missions.get(session, user.fleet, v)
        for v in range(head.base_mission_version, head.mission_version + 1)
    }
    groups = list(model.history())
    rules = {
        g[0].version: model.rules(g[0])
        for g in groups
        if isinstance(g[0], journal.Correction | journal.Lift)
    }
    history = _History(
        user_id=user.user_id,
        algorithm=user.algorithm,
        base_doc=model.base_document(),
        base_layout=head.base_mission_version,
        layouts=layouts,
        groups=groups,
        rules=rules,
        asked=[],
        lengths=[],
        logged=[],
        reward=[],
    )
    learner = _start(spec, history)
    layout = history.base_layout

    def move(current: TabularLearner[Any], old: int, new: int) -> TabularLearner[Any]:
        for version in range(old + 1, new + 1):
            current = remap_learner(current, layouts[version].mission, layouts[version].renames)
        return current

    refused = 0
    for group in groups:
        try:
            learner, layout = apply(
                learner, group, layout=layout, rules=lambda e: rules[e.version], move=move
            )
        except (ValueError, KeyError):
            refused += 1
    return learner, refused


# ---------------------------------------------------------------------------------------------
# The fleet


def _rng(fleet: str, what: str) -> np.random.Generator:
    digest = hashlib.sha256(f"{fleet}\x00{what}".encode()).digest()
    return np.random.default_rng([int(w) for w in np.frombuffer(digest[:16], dtype="<u4")])


def _difference(
    steps: Steps, found: Estimate, logged_value: float, estimator: str, rng: np.random.Generator
) -> Difference:
    """Candidate (``found``) minus logged (``logged_value``), with the expanded percentile
    interval of the difference over bootstrap resamples of the people (the episodes, with fewer
    than ``MIN_CLUSTERS`` people), the same resample for both, reaching as far for what the logs
    do not show as the candidate's own interval (:func:`app.learning.offpolicy.unseen_margins`)."""
    assert found.value is not None
    value = found.value - logged_value
    if steps.n_clusters >= MIN_CLUSTERS:
        grouped, method = steps, "bootstrap"
    else:
        grouped = dataclasses.replace(steps, cluster=np.arange(steps.n_episodes, dtype=np.int64))
        method = "bootstrap-episodes"
    _, group = np.unique(grouped.cluster, return_inverse=True)
    n = int(group.max()) + 1
    returns = grouped.returns()
    top = np.bincount(group, weights=returns, minlength=n)
    bottom = np.bincount(group, minlength=n).astype(np.float64)
    probabilities = np.full(n, 1.0 / n)
    block = max(1, _BLOCK // n)
    out = np.empty(N_BOOT)
    for first in range(0, N_BOOT, block):
        size = min(block, N_BOOT - first)
        counts = rng.multinomial(n, probabilities, size=size).astype(np.float64)
        candidate = resampled(grouped, estimator, DEFAULT_CLIP, counts)
        logged = (counts @ top) / (counts @ bottom)
        out[first : first + size] = candidate - logged
    level = expanded_level(CONFIDENCE, n)
    low, high = np.quantile(out, [1.0 - level, level])
    below, above = unseen_margins(steps, estimator, found.value, found.weight_mean)
    return Difference(float(value), float(low) - below, float(high) + above, method, CONFIDENCE)


def _steps(cluster: list[int], lengths: list[int], columns: Mapping[str, list[Any]]) -> Steps:
    """The people's episodes as :class:`Steps`; a column not given is the logging learner's
    own (target 1, no model, nothing unsupported)."""
    offsets = np.concatenate(([0], np.cumsum(np.asarray(lengths, dtype=np.int64)))).astype(np.int64)
    n = int(offsets[-1])

    def column(name: str, absent: float = 0.0) -> FloatArray:
        parts = columns.get(name)
        if parts is None:
            return np.full(n, absent)
        return np.concatenate(parts) if parts else np.zeros(0)

    return Steps(
        cluster=np.asarray(cluster, dtype=np.int64),
        offsets=offsets,
        logged=column("logged"),
        target=column("target", 1.0),
        reward=column("reward"),
        q_hat=column("q_hat"),
        v_hat=column("v_hat"),
        unsupported=column("unsupported"),
    )


def _people(database: Database, fleet: str) -> Iterator[list[UserRow]]:
    after: tuple[str, str] | None = None
    while True:
        with database.transaction(write=False) as session:
            page = users_repo.list_page(session, fleet=fleet, after=after, limit=PEOPLE_PAGE)
        if page:
            yield page
        if len(page) < PEOPLE_PAGE:
            return
        after = (page[-1].fleet, page[-1].user_id)


class _Priors:
    """The fleet's prior as a candidate with ``fleet_prior`` true starts a person from it, when
    that person started fresh: the prior the service would build for a newcomer today (the
    fleet's people who take part, learning with the candidate's algorithm, with enough
    episodes, laid out for the person's base mission; ``ATTUNE_PRIOR_*``), the person
    themselves left out. Today's, not the one of the day they came: it holds what the others
    learned since, which favours the candidate (docs/method.md §17). None where the service
    would start them fresh too (too few contributors, a person who keeps out of the prior, an
    algorithm that always starts fresh). Each contributor's model is opened once per
    evaluation."""

    def __init__(self, ctx: ServiceContext, fleet: str) -> None:
        self.ctx, self.fleet = ctx, fleet
        self._pks: dict[tuple[str, int], list[int]] = {}
        self._learners: dict[int, TabularLearner[Any]] = {}

    def for_person(
        self, session: Session, spec: CandidateSpec, history: _History, user: UserRow
    ) -> TabularLearner[Any] | None:
        settings = self.ctx.settings
        if not history.takes_part or spec.algorithm in FRESH_ONLY:
            return None
        version = history.base_layout
        found = self._pks.get((spec.algorithm, version))
        if found is None:
            found = models_repo.prior_contributors(
                session,
                fleet=self.fleet,
                algorithm=spec.algorithm,
                mission_version=version,
                min_episodes=settings.prior_min_episodes,
                limit=settings.prior_max_contributors + 1,
            )
            self._pks[(spec.algorithm, version)] = found
        others = [pk for pk in found if pk != user.id][: settings.prior_max_contributors]
        if len(others) < settings.prior_min_contributors:
            return None
        learners = []
        for pk in others:
            if pk not in self._learners:
                contributor = users_repo.by_pk(session, pk)
                if contributor is None:
                    continue
                self._learners[pk] = PersonModel.open(session, self.ctx, contributor).learner
            learners.append(self._learners[pk])
        return population_prior(
            spec.algorithm,
            spec.full_params,
            history.layouts[version].mission,
            learners,
            strength=settings.prior_strength,
        )


def evaluate_fleet(
    database: Database,
    ctx: ServiceContext,
    fleet: str,
    candidates: Sequence[CandidateSpec],
    *,
    since: dt.datetime | None = None,
    until: dt.datetime | None = None,
    estimator: str = DEFAULT_ESTIMATOR,
    progress: Callable[[int, int], None] | None = None,
) -> FleetEvaluation:
    """Each candidate's value per encounter with ``fleet``'s people, estimated from the fleet's
    stored logs (see the module's docstring), beside what the robots earn now; ``progress(done,
    total)`` after each person. Naive times are UTC. :class:`NotFound` for a fleet without
    people; ``ValueError`` for an unknown estimator or no candidate."""
    if estimator not in ESTIMATORS:
        raise ValueError(f"unknown estimator {estimator!r}: one of {', '.join(ESTIMATORS)}.")
    if not candidates:
        raise ValueError("no candidate to evaluate.")
    since, until = _aware(since), _aware(until)
    with database.transaction(write=False) as session:
        counts = users_repo.fleet_counts(session)
    if fleet not in counts:
        raise NotFound(f"No fleet {fleet!r}: no person of this database is in it.")
    total = counts[fleet][0]
    skipped: dict[str, int] = {}
    people_skipped: list[tuple[str, str]] = []
    learners: dict[str, int] = {}
    cluster: list[int] = []
    lengths: list[int] = []
    logged_columns: dict[str, list[Any]] = {"logged": [], "reward": []}
    candidate_columns: list[dict[str, list[Any]]] = [
        {"target": [], "unsupported": [], "q_hat": [], "v_hat": []} for _ in candidates
    ]
    refused = [0] * len(candidates)
    counted: list[tuple[str, str, int]] = []  # (user id, algorithm, episodes)
    priors = _Priors(ctx, fleet)
    done = 0
    for page in _people(database, fleet):
        for user in page:
            learners[user.algorithm] = learners.get(user.algorithm, 0) + 1
            theirs = [spec.for_person(user) for spec in candidates]
            try:
                with database.transaction(write=False) as session:
                    history = _read_person(session, ctx, user, since, until)
                    for spec in theirs:
                        if history.lengths and _wants_prior(spec, history):
                            history.priors[spec.key] = priors.for_person(
                                session, spec, history, user
                            )
                replays = (
                    [
                        _replay(fleet, history, spec, model=estimator in MODEL_ESTIMATORS)
                        for spec in theirs
                    ]
                    if history.lengths
                    else []
                )
            except (ValueError, KeyError, LookupError, StateFormatError) as exc:
                # A history that cannot be replayed (a broken database): said, not hidden.
                people_skipped.append((user.user_id, str(exc)))
                history = None
            if history is not None:
                for why, n in history.skipped.items():
                    skipped[why] = skipped.get(why, 0) + n
            if history is not None and history.lengths:
                label = len(counted)
                counted.append((history.user_id, history.algorithm, len(history.lengths)))
                cluster.extend([label] * len(history.lengths))
                lengths.extend(history.lengths)
                logged_columns["logged"].append(np.asarray(history.logged))
                logged_columns["reward"].append(np.asarray(history.reward))
                for i, replayed in enumerate(replays):
                    for name in ("target", "unsupported", "q_hat", "v_hat"):
                        candidate_columns[i][name].append(getattr(replayed, name))
                    refused[i] += replayed.refused
            done += 1
            if progress is not None:
                progress(done, max(total, done))

    logged_steps = _steps(cluster, lengths, logged_columns)
    logged = on_policy(logged_steps, n_boot=N_BOOT, rng=_rng(fleet, "logged"))
    returns = logged_steps.returns()
    observed = (float(returns.min()), float(returns.max())) if returns.size else None
    results: list[CandidateResult] = []
    per_person: list[list[Estimate]] = []
    for i, spec in enumerate(candidates):
        steps = _steps(cluster, lengths, {**logged_columns, **candidate_columns[i]})
        found = estimate(steps, estimator, n_boot=N_BOOT, rng=_rng(fleet, spec.key))
        reason = evidence(found, observed)
        difference = None
        if not reason and logged.enough:
            assert found.value is not None
            assert logged.value is not None
            difference = _difference(
                steps, found, logged.value, estimator, _rng(fleet, f"{spec.key}/diff")
            )
        results.append(
            CandidateResult(
                spec,
                found,
                difference,
                reason,
                verdict(spec.label, difference, reason),
                refused[i],
            )
        )
        per_person.append(
            per_cluster(steps, estimator, n_boot=N_BOOT, rng=_rng(fleet, f"{spec.key}/people"))
            if steps.n_episodes
            else []
        )
    persons = []
    people_rng = _rng(fleet, "logged/people")
    for label, (user_id, algorithm, n_episodes) in enumerate(counted):
        mine = logged_steps.select(logged_steps.cluster == label)
        persons.append(
            PersonResult(
                user_id=user_id,
                algorithm=algorithm,
                episodes=n_episodes,
                mean_return=float(np.mean(mine.returns())),
                logged=on_policy(mine, n_boot=N_BOOT, rng=people_rng),
                candidates=tuple(rows[label] for rows in per_person),
            )
        )
    return FleetEvaluation(
        fleet=fleet,
        since=since,
        until=until,
        estimator=estimator,
        people=done,
        people_counted=len(counted),
        episodes=logged_steps.n_episodes,
        learners=dict(sorted(learners.items())),
        logged=logged,
        candidates=tuple(results),
        persons=tuple(persons),
        skipped=dict(sorted(skipped.items())),
        people_skipped=tuple(people_skipped),
    )
