"""What the pages show, derived only from the v1 API's documents (``ProfileOut``, ``ModelOut``,
``StatsOut``, ``EpisodeTrace``): the profile's words, local times, number formats, the heatmap,
the "why this action" rows, the reward curve.

Nothing here reads the database or the learner: every number these pieces put on a page is one
the API returns for the same user, or a product of such numbers (the heatmap's expected service),
so the console and the API can never disagree.
"""

from __future__ import annotations

import datetime as dt
import math
import re
import zoneinfo
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple
from urllib.parse import quote, urlencode

from app.daily import DailyTime
from app.learning import Mission
from app.learning.guidance import Reason, ReasonCode
from app.schemas.audit import ViewOut
from app.schemas.common import ActionOut
from app.schemas.models import ActionBelief, ContextModel, ModelOut, StartedFrom, StateModel
from app.schemas.profile import (
    CorrectionOut,
    ProfileContext,
    ProfileOut,
    RobotWill,
    RolloutArmOut,
    Wanted,
)
from app.schemas.users import UserOut
from app.services.evaluation import CandidateSpec

__all__ = [
    "CERTAINTY",
    "Expectation",
    "HeatCell",
    "HeatRow",
    "ProfileCell",
    "ProfileRow",
    "StateRows",
    "action_arg",
    "action_label",
    "correction_status",
    "correction_words",
    "curve",
    "days_words",
    "episode_words",
    "expectation",
    "fmt_aware",
    "fmt_count",
    "fmt_local",
    "fmt_measure",
    "fmt_offset",
    "fmt_pct",
    "fmt_q",
    "fmt_rate",
    "fmt_reward",
    "heat_class",
    "heatmap",
    "initiate_p",
    "learner_summary",
    "name_words",
    "or_list",
    "profile_grid",
    "response_words",
    "retention_words",
    "robot_words",
    "state_label",
    "state_words",
    "tenth",
    "unique_best",
    "user_url",
    "wanted_words",
    "why_rows",
]

DASH = "—"  # a value the learner has no notion of (or no data yet)


# -- number formats (the browser tests parse these back) --------------------------------------
class UserAt(NamedTuple):
    """A user by id and fleet: what a console address needs."""

    user_id: str
    fleet: str


def user_url(user: UserOut | UserAt, tail: str = "", **params: object) -> str:
    """A console address of a user's page (its fleet named, so that an admin's links work for
    every fleet): ``user_url(user, "/why", time_slot="noon")``, under the console (templates
    write ``url(v.user_url(...))``, routes redirect to it)."""
    query = urlencode({"fleet": user.fleet, **{k: v for k, v in params.items() if v is not None}})
    return f"/users/{quote(user.user_id, safe='')}{tail}?{query}"


def fmt_pct(p: float | None, digits: int = 1) -> str:
    """A probability or rate as a percentage: 0.8312 -> "83.1%"."""
    return DASH if p is None else f"{p * 100:.{digits}f}%"


fmt_rate = fmt_pct


def fmt_q(q: float | None) -> str:
    return DASH if q is None else f"{q:.2f}"


def fmt_reward(r: float | None) -> str:
    return DASH if r is None else f"{r:.1f}"


def fmt_count(v: float | None) -> str:
    """Visit counts: whole numbers as such, weighted ones (w_I1, forgetting) with 2 decimals."""
    if v is None:
        return DASH
    return str(int(v)) if float(v).is_integer() else f"{v:.2f}"


def fmt_measure(m: float | None) -> str:
    """The temporal measure spans e^-30 .. 1e6: three significant digits."""
    return DASH if m is None else f"{m:.3g}"


def tenth(p: float) -> int:
    """0..10: the 10% step nearest to ``p``."""
    return min(10, max(0, math.floor(p * 10 + 0.5)))


def heat_class(p: float | None) -> str:
    """A CSS class per 10% step (a class, not an inline style: the pages' CSP forbids those)."""
    return "heat-none" if p is None else f"heat-{tenth(p)}"


# -- labels ----------------------------------------------------------------------------------
_KEY_PARAM = {
    "hri": ("tau", "τ"),
    "dts": ("forgetting", "λ"),
    "dts-adapt": ("forgetting", "λ"),
    "dts-routine": ("forgetting", "λ"),
    "rmax": ("m", "m"),
    "qlearning": ("exploration", ""),
}
_EXPLORATION = {"epsilon": "ε-greedy", "boltzmann": "Boltzmann"}


def learner_summary(algorithm: str, params: dict[str, object]) -> str:
    """The learner and the parameter that tells its variants apart: ``hri τ=0.01``."""
    key, symbol = _KEY_PARAM.get(algorithm, ("", ""))
    if key not in params:
        return algorithm
    if symbol:
        return f"{algorithm} {symbol}={params[key]}"
    return f"{algorithm} {_EXPLORATION.get(str(params[key]), params[key])}"


def action_arg(action: ActionOut) -> str | None:
    """What an action is about, where its name needs it: ``tea`` for ``infer_detail(tea)``."""
    if action.kind == "infer_detail":
        return action.detail
    if action.kind in ("respond", "infer_type", "query_detail"):
        return action.service
    return None


def action_label(action: ActionOut) -> str:
    """``infer_detail(tea)``, ``query_detail(ProvideDrink)``, ``perform``, ``initiate`` ..."""
    arg = action_arg(action)
    return action.kind if arg is None else f"{action.kind}({arg})"


def state_label(state: StateModel) -> str:
    parts = [p for p in (state.service, state.detail) if p]
    return f"{state.state}({', '.join(parts)})" if parts else state.state


_STATE_WORDS = {
    "OBSERVE": "An event starts: the robot sees the person and may offer help or stay passive.",
    "REQUEST": "The person asked for {service}: the robot responds.",
    "ENGAGED": "The person accepted the robot's offer; the service is not known yet.",
    "TYPE_KNOWN": "The robot believes {service} is wanted; the detail is not known yet.",
    "DETAIL_KNOWN": "The robot believes {service} / {detail} is wanted: it performs it.",
}


def state_words(state: StateModel) -> str:
    return _STATE_WORDS.get(state.state, state.state).format(
        service=state.service, detail=state.detail
    )


# -- the heatmap -------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Expectation:
    """What the model expects in a context, read from the robot's policy once the person has
    accepted its offer (state ENGAGED), where it may guess (infer) or ask (query):

    - ``service``, ``detail``: the (type, detail) it would most likely perform by guessing both,
      the largest P(infer_type(k)) x P(infer_detail(d) | type k); ``None`` while no pair stands
      out (a tie: nothing learned tells them apart);
    - ``p_guess``: that largest probability, the chance that it performs exactly (service,
      detail) without asking anything; ``None`` with no pair;
    - ``p_ask``: the chance that it asks something first: the type, or the detail after
      guessing the type.
    """

    service: str | None
    detail: str | None
    p_guess: float | None
    p_ask: float


@dataclass(frozen=True, slots=True)
class HeatCell:
    time_slot: str
    situation: str
    p_initiate: float | None
    episodes: int  # episodes begun in this context (the visits of its root pairs)
    expected: Expectation | None  # None: the robot was never engaged in this context


@dataclass(frozen=True, slots=True)
class HeatRow:
    time_slot: str
    hours: str
    cells: list[HeatCell]


def _state(context: ContextModel, kind: str, service: str | None = None) -> StateModel | None:
    for s in context.states:
        if s.state == kind and (service is None or s.service == service):
            return s
    return None


def initiate_p(context: ContextModel) -> float | None:
    observe = _state(context, "OBSERVE")
    if observe is None:
        return None
    return next((a.p for a in observe.actions if a.action.kind == "initiate"), None)


def unique_best(actions: Sequence[ActionBelief]) -> ActionBelief | None:
    """The most probable action, or None when two or more share the top probability."""
    ranked = sorted(actions, key=lambda a: a.p, reverse=True)
    if not ranked or (
        len(ranked) > 1 and math.isclose(ranked[0].p, ranked[1].p, rel_tol=1e-9, abs_tol=1e-12)
    ):
        return None
    return ranked[0]


def expectation(context: ContextModel) -> Expectation | None:
    """What the model expects in ``context`` (see ``Expectation``); None if never engaged."""
    engaged = _state(context, "ENGAGED")
    ever = any(a.visits > 0 for s in context.states if s.state != "OBSERVE" for a in s.actions)
    if engaged is None or not ever:
        return None
    p_ask = sum(a.p for a in engaged.actions if a.action.kind == "query_type")
    guesses: list[tuple[float, str, str]] = []
    for guess in engaged.actions:
        if guess.action.kind != "infer_type" or guess.action.service is None:
            continue
        known = _state(context, "TYPE_KNOWN", guess.action.service)
        if known is None:
            continue
        for a in known.actions:
            if a.action.kind == "query_detail":
                p_ask += guess.p * a.p
            elif a.action.kind == "infer_detail" and a.action.detail is not None:
                guesses.append((guess.p * a.p, guess.action.service, a.action.detail))
    guesses.sort(key=lambda g: g[0], reverse=True)
    if not guesses or (
        len(guesses) > 1 and math.isclose(guesses[0][0], guesses[1][0], rel_tol=1e-9, abs_tol=1e-12)
    ):
        return Expectation(None, None, None, p_ask)
    p, service, detail = guesses[0]
    return Expectation(service, detail, p, p_ask)


def heatmap(model: ModelOut, mission: Mission) -> list[HeatRow]:
    """Time slots (rows) x situations (columns), in the mission's order."""
    by_context = {(c.time_slot, c.situation): c for c in model.contexts}
    rows = []
    for slot in mission.time_slots:
        cells = []
        for situation in mission.situations:
            c = by_context.get((slot.name, situation))
            if c is None:
                cells.append(HeatCell(slot.name, situation, None, 0, None))
                continue
            observe = _state(c, "OBSERVE")
            episodes = sum(a.visits for a in observe.actions) if observe else 0
            cells.append(HeatCell(slot.name, situation, initiate_p(c), episodes, expectation(c)))
        hours = f"{slot.start:%H:%M}–{slot.end:%H:%M}"
        rows.append(HeatRow(slot.name, hours, cells))
    return rows


# -- "why this action" -------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class StateRows:
    label: str
    words: str
    state: StateModel
    chosen: int | None  # index of the most probable action, if one is (no tie, no single)


def why_rows(context: ContextModel) -> list[StateRows]:
    out = []
    for s in context.states:
        best = unique_best(s.actions) if len(s.actions) > 1 else None
        chosen = next((i for i, a in enumerate(s.actions) if a is best), None)
        out.append(StateRows(state_label(s), state_words(s), s, chosen))
    return out


# -- the cumulative reward curve -----------------------------------------------------------
def curve(cumulative: Sequence[float], max_points: int = 4000) -> tuple[list[int], list[float]]:
    """(episode index, cumulative reward) for the chart, at most ~``max_points`` points.

    A long history is thinned by keeping each bucket's lowest and highest point (in order), so
    every dip and jump of the curve survives while the page stays small.
    """
    n = len(cumulative)
    if n <= max_points:
        return list(range(n)), [float(v) for v in cumulative]
    buckets = max_points // 2
    size = n / buckets
    xs: list[int] = []
    for b in range(buckets):
        lo, hi = int(b * size), min(n, int((b + 1) * size))
        if hi <= lo:
            continue
        chunk = range(lo, hi)
        a = min(chunk, key=lambda i: cumulative[i])
        z = max(chunk, key=lambda i: cumulative[i])
        xs.extend(sorted({a, z}))
    if xs[-1] != n - 1:
        xs.append(n - 1)
    if xs[0] != 0:
        xs.insert(0, 0)
    return xs, [float(cumulative[i]) for i in xs]


# -- local times -----------------------------------------------------------------------------
def fmt_offset(minutes: int) -> str:
    """Minutes east of UTC as people write it: 480 -> "UTC+8", 330 -> "UTC+5:30", 0 -> "UTC"."""
    if minutes == 0:
        return "UTC"
    sign = "+" if minutes > 0 else "−"
    hours, rest = divmod(abs(minutes), 60)
    return f"UTC{sign}{hours}" + (f":{rest:02d}" if rest else "")


def fmt_local(at: dt.datetime | None, offset: int | None) -> str:
    """A moment in the person's local time, ``offset`` minutes east of UTC, with the offset:
    "2026-11-01 09:00 (UTC+8)"; without an offset (the robot sent none, or the moment was
    stored before offsets were kept): in UTC, and said so, "2026-11-01 01:00 UTC"."""
    if at is None:
        return DASH
    if at.tzinfo is None:
        at = at.replace(tzinfo=dt.UTC)
    if offset is None:
        return f"{at.astimezone(dt.UTC):%Y-%m-%d %H:%M} UTC"
    local = at.astimezone(dt.timezone(dt.timedelta(minutes=offset)))
    return f"{local:%Y-%m-%d %H:%M} ({fmt_offset(offset)})"


def fmt_aware(at: dt.datetime | None) -> str:
    """A moment already in the person's local time (its own offset): "2026-11-01 09:00
    (UTC+8)"."""
    if at is None:
        return DASH
    offset = at.utcoffset()
    return fmt_local(at, 0 if offset is None else int(offset.total_seconds() // 60))


# -- the profile, in the staff's words -------------------------------------------------------
_CAMEL = re.compile(r"(?<=[a-z0-9])(?=[A-Z])")


def name_words(name: str | None) -> str:
    """A mission name as words: "ProvideDrink" -> "Provide drink", "today_agenda" -> "today
    agenda"."""
    if not name:
        return ""
    words = _CAMEL.sub(" ", name).replace("_", " ").split()
    if not words:
        return name
    first, rest = words[0], [w.lower() if not w.isupper() else w for w in words[1:]]
    return " ".join([first, *rest])


def wanted_words(
    wanted: Wanted | None, *, service: str | None = None, detail: str | None = None
) -> str:
    """ "Provide drink (tea)"; the service alone when no detail is known."""
    if wanted is not None:
        service, detail = wanted.service, wanted.detail
    if not service:
        return "Nothing in particular"
    return name_words(service) + (f" ({name_words(detail)})" if detail else "")


def robot_words(will: RobotWill) -> str:
    """What the robot will do, in a few words."""
    if will.action == "stay_away":
        return "Stays away"
    if will.action == "wait_to_be_asked":
        return "Waits to be asked"
    if will.asks_first or not will.service:
        return "Offers help and asks what first"
    return "Offers it without asking"


CERTAINTY = {
    "confident": "Confident",
    "tentative": "Tentative: still learning",
    "unknown": "Not enough to say yet",
}

_EPISODE = {
    "I1": "Asked for help",
    "I2": "Accepted the offer",
    "I3": "Turned the offer down",
    "none": "No conversation",
}


def episode_words(interaction_class: str, initiator: str | None = None) -> str:
    """What happened in an episode, in words (the engineers' interaction class)."""
    return _EPISODE.get(interaction_class, interaction_class)


def or_list(items: Sequence[str]) -> str:
    """ "tea, coffee or water"."""
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + f" or {items[-1]}"


_RESPONSE = {
    "accepted": "accepted",
    "rejected": "turned it down",
    "answered": "answered",
    "human_request": "asked for",
    "none": "did nothing",
    "terminated": "ended the talk",
}


def response_words(response: str | None) -> str:
    """What the person did, in words ("asked for", "turned it down"); None: not yet."""
    if response is None:
        return "no answer yet"
    return _RESPONSE.get(response, response)


def correction_words(c: CorrectionOut, mission: Mission | None = None) -> str:
    """What a correction says: "Prefers Provide drink (tea)", "Avoid Brief information",
    "Quiet: the robot does not offer help" (with the mission's labels when given)."""
    what = (
        wanted_words(None, service=c.service, detail=c.detail)
        if mission is None
        else wanted_label(mission, c.service, c.detail)
    )
    if c.kind == "prefers":
        return f"Prefers {what}"
    if c.kind == "avoid":
        return f"Do not offer {what}"
    return "Quiet: the robot does not offer help"


def correction_status(c: CorrectionOut, who: str = "the person") -> str:
    if c.status == "overridden":
        return f"Overridden by {who}'s own answers"
    if c.status == "lifted":
        return "Lifted"
    if c.status == "idle":
        return "Not in use: the mission no longer has this time slot, situation or service"
    return "In force"


@dataclass(frozen=True, slots=True)
class ProfileCell:
    time_slot: str
    situation: str
    context: ProfileContext | None  # None: the profile does not speak of it (no data at all)
    staff: tuple[CorrectionOut, ...] = ()  # the staff corrections in force here

    @property
    def by_staff(self) -> bool:
        return bool(self.staff) or (self.context is not None and self.context.source == "staff")

    @property
    def certainty(self) -> str:
        return self.context.certainty if self.context is not None else "unknown"


@dataclass(frozen=True, slots=True)
class ProfileRow:
    time_slot: str
    hours: str
    cells: list[ProfileCell]


def profile_grid(profile: ProfileOut, mission: Mission) -> list[ProfileRow]:
    """Time slots (rows) x situations (columns), in the mission's order."""
    by_context = {(c.time_slot, c.situation): c for c in profile.contexts}
    in_force = {c.correction_id: c for c in profile.corrections if c.status == "in_force"}

    def cell(slot: str, situation: str) -> ProfileCell:
        context = by_context.get((slot, situation))
        staff = (
            ()
            if context is None
            else tuple(in_force[i] for i in context.corrections if i in in_force)
        )
        return ProfileCell(slot, situation, context, staff)

    return [
        ProfileRow(
            slot.name,
            f"{slot.start:%H:%M}–{slot.end:%H:%M}",
            [cell(slot.name, situation) for situation in mission.situations],
        )
        for slot in mission.time_slots
    ]


# -- labels: the mission's words for its names ------------------------------------------------
def label(mission: Mission, name: str | None) -> str:
    """The words staff read for a mission name: the mission's label, or a readable form of
    the id ("ProvideDrink" -> "Provide drink")."""
    return mission.label(name)


def wanted_label(mission: Mission, service: str | None, detail: str | None) -> str:
    """ "a drink (tea)": the service's label, and the choice's in brackets."""
    if not service:
        return "Nothing in particular"
    return label(mission, service) + (f" ({label(mission, detail)})" if detail else "")


# -- times in the fleet's time zone -----------------------------------------------------------
def zone_name(mission: Mission) -> str:
    """The fleet's time zone as the pages name it: "Europe/London", "UTC"."""
    return mission.time_zone


def fmt_zone(at: dt.datetime | None, zone: str) -> str:
    """A moment in the fleet's time zone, without the zone's name (each page says it once):
    "2026-11-03 09:12"."""
    if at is None:
        return DASH
    if at.tzinfo is None:
        at = at.replace(tzinfo=dt.UTC)
    return f"{at.astimezone(zoneinfo.ZoneInfo(zone)):%Y-%m-%d %H:%M}"


def zone_note(zone: str) -> str:
    """What a page says once about its times."""
    return f"Times are in the fleet's time zone, {zone}."


# -- an episode, step by step, in words -------------------------------------------------------
def _act_words(mission: Mission, kind: str, service: str | None, detail: str | None) -> str:
    what = label(mission, service)
    if kind == "initiate":
        return "offered help"
    if kind == "pass":
        return "waited, without offering anything"
    if kind == "respond":
        return f"took up the request for {what}"
    if kind == "query_type":
        return "asked what was wanted"
    if kind == "infer_type":
        return f"guessed {what} was wanted"
    if kind == "query_detail":
        return f"asked which {what}" if what else "asked which one"
    if kind == "infer_detail":
        return f"guessed {label(mission, detail)}"
    if kind == "perform":
        return f"brought {label(mission, detail)} ({what})" if detail else f"brought {what}"
    return "did something this console cannot name"


def robot_step_words(mission: Mission, decision: object) -> str:
    """What the robot did at one decision, the silent steps first, in words: "guessed reading
    aloud was wanted, asked which one"."""
    chain = getattr(decision, "chain", [])
    action = getattr(decision, "action")  # noqa: B009 - decisions of two schemas
    steps = [_act_words(mission, s.action.kind, s.action.service, s.action.detail) for s in chain]
    if action.kind == "query_detail" and chain and chain[-1].action.kind == "infer_type":
        steps.append("asked which one")
    else:
        steps.append(_act_words(mission, action.kind, action.service, action.detail))
    text = ", ".join(steps)
    return text[:1].upper() + text[1:]


def person_step_words(
    mission: Mission, who: str, response: str | None, service: str | None, detail: str | None
) -> str:
    """What the person did in answer, in words: "Mrs. Lin accepted", "answered: a phone
    call"."""
    thing = label(mission, detail) if detail else label(mission, service)
    if response is None:
        return f"Waiting for {who}'s answer"
    if response == "accepted":
        return f"{who} accepted"
    if response == "rejected":
        return f"{who} turned it down"
    if response == "answered":
        return f"{who} answered: {thing}" if thing else f"{who} answered"
    if response == "human_request":
        return f"{who} asked for {thing}" if thing else f"{who} asked for help"
    if response == "none":
        return f"{who} did not react"
    if response == "terminated":
        return f"{who} ended the conversation"
    return f"{who}: {response}"


def feedback_words(feedback: str) -> str:
    return {"positive": "pleased", "negative": "displeased"}.get(feedback, feedback)


def outcome_words(total_reward: float) -> str:
    """How the episode went, for staff: the sign of its reward."""
    if total_reward > 0:
        return "went well"
    if total_reward < 0:
        return "went badly"
    return "neither well nor badly"


# -- what drives a decision, and the learner in use, in words ---------------------------------
_LEARNERS = {
    "hri": (
        "It learns from each answer of the person how welcome each action is, and sets aside "
        "old answers that contradict the latest one, so a changed wish is followed at once. "
        "Actions that did well but were not tried for a while get another chance now and then."
    ),
    "dts": (
        "It keeps, for each action, a running estimate of how often the person welcomes it, in "
        "which older answers count less and less, and draws its choice from those estimates: "
        "the more sure it is that an action is welcome, the more often it takes it."
    ),
    "dts-adapt": (
        "It keeps, for each action, a running estimate of how often the person welcomes it, "
        "draws its choice from those estimates, and lets old answers count less as soon as the "
        "person's reactions start to differ from what it expected, so a changed wish is "
        "followed quickly."
    ),
    "dts-routine": (
        "It learns, in each situation, the service and detail the person last took there, and "
        "brings them when it offers help; once the person turns them down, it asks which "
        "service and which detail before guessing there again, and where it knows nothing yet "
        "it asks rather than guesses. Where it holds no routine, it draws its choice from "
        "running estimates of how often the person welcomes each action."
    ),
    "rmax": (
        "It assumes untried actions are excellent until it has tried each a few times, then "
        "plans with what it learned of the person."
    ),
    "qlearning": (
        "It learns directly how much each action pays off from the person's answers, and now "
        "and then tries another action to keep learning."
    ),
}


def learner_words(algorithm: str) -> str:
    """How the learner in use chooses, in words staff can read."""
    return _LEARNERS.get(algorithm, "It learns from the person's answers.")


@dataclass(frozen=True, slots=True)
class Drivers:
    """What drives the robot's decision in one context, for the "why" page's words."""

    corrections: tuple[CorrectionOut, ...]  # the staff corrections of the context, not lifted
    prior: int | None  # the fleet's prior: how many people it averaged (None: not from it)
    episodes: int  # the person's episodes in this context


def episodes_in(context: ContextModel) -> int:
    """Episodes begun in a context: the visits of its root's actions."""
    observe = _state(context, "OBSERVE")
    return sum(a.visits for a in observe.actions) if observe else 0


def drivers(started: StartedFrom, corrections: Sequence[CorrectionOut], episodes: int) -> Drivers:
    return Drivers(
        tuple(c for c in corrections if c.status != "lifted"),
        started.contributors if started.kind == "fleet_prior" else None,
        episodes,
    )


_PAGE_WORDS = {
    "console.profile": "the profile",
    "console.details": "the details",
    "console.why": "why an action",
    "console.episodes": "the episodes",
    "console.trace": "an episode",
    "export": "the export",
    "evaluation": "a what-if evaluation",
}


def looked_words(view: ViewOut, me: str, zone: str) -> str:
    """One earlier look at a person, for the page's header: "night-shift, 2026-12-02 02:14 (the
    profile)"; the reader's own key is "you"."""
    who = "you" if view.actor.key_id == me else (view.actor.name or f"key {view.actor.key_id[:12]}")
    where = _PAGE_WORDS.get(view.what, f"the API's {view.what}" if view.via == "api" else view.what)
    return f"{who}, {fmt_zone(view.at, zone)} ({where})"


def key_label(key_id: str, names: dict[str, str]) -> str:
    """A key as staff know it: its name ("night-shift"), or "a key" with its id's start."""
    name = names.get(key_id)
    return name if name else f"key {key_id[:12]}"


_P_WORDS = {
    "hri": "HRI draws from exp(Pref/τ), with Pref = Q/Vmax + M (eqs. 5–6).",
    "dts": "DTS draws models of the person from its discounted counts (λ) and solves each; P is "
    "the share of the drawn models in which this action is the best (docs/method.md §8). Q, M "
    "and t do not enter it.",
    "dts-adapt": "dts-adapt, like DTS, draws models of the person from its discounted counts "
    "(λ) and solves each; P is the share of the drawn models in which this action is the best "
    "(docs/method.md §8). Q, M and t do not enter it.",
    "dts-routine": "dts-routine follows the person's routine in this context where it trusts "
    "it (P = 1 for its offer, service and detail) and asks where the routine was refused or none "
    "is held (P = 1 for the question); elsewhere, like DTS, it draws models of the person from "
    "its discounted counts (λ) and solves each, and P is the share of the drawn models in which "
    "this action is the best (docs/method.md §8). Q, M and t do not enter it.",
    "rmax": "R-max takes the action of the highest optimistic Q, ties shared equally.",
    "qlearning": "Q-learning explores around its Q values (ε-greedy or Boltzmann).",
}


def p_words(algorithm: str) -> str:
    """How the learner in use turns its numbers into P, for the engineers' legend."""
    return _P_WORDS.get(algorithm, "")


def refusal_words(reasons: Sequence[Reason], mission: Mission, fleet: str) -> str:
    """The learning core's reasons for refusing a correction, as the form says them."""
    reason = reasons[0]
    code, kind = reason.code, reason.kind.value
    if code is ReasonCode.NEEDS_SERVICE:
        if kind == "prefers":
            return "Choose what the person prefers."
        return "Choose what the robot should not offer."
    if code is ReasonCode.UNKNOWN_SERVICE:
        return (
            f"The robots of fleet {fleet} do not offer “{label(mission, reason.got)}” any more: "
            "choose another service."
        )
    choices = or_list([label(mission, d) for d in reason.allowed])
    service = label(mission, reason.service)
    if code is ReasonCode.NEEDS_DETAIL:
        return f"Choose the person's choice of {service}: {choices}."
    if code is ReasonCode.UNKNOWN_DETAIL:
        return f"“{label(mission, reason.got)}” is not a choice of {service}: choose {choices}."
    if code in (ReasonCode.UNKNOWN_TIME_SLOT, ReasonCode.UNKNOWN_SITUATION):
        return "This box is not part of the fleet's mission any more: choose another box."
    if code is ReasonCode.BAD_ID:
        return "The form is incomplete (its number is missing): reload the page and try again."
    return "The robot should stay quiet here: leave the service and the choice empty."


def cap(text: str) -> str:
    """The first letter upper case, the rest as written: "lunchtime" -> "Lunchtime"."""
    return text[:1].upper() + text[1:]


def days_words(days: int) -> str:
    """A number of days in words: 1 day, 90 days, 1,000 days."""
    return "1 day" if days == 1 else f"{days:,} days"


def retention_words(days: int | None, runs_at: DailyTime | None) -> str:
    """What a fleet's retention window means, in one sentence: when its episodes go and what
    stays. ``runs_at``: the service's own time of day for the clean-up (``None``: the
    operator runs it)."""
    if days is None:
        return "Every episode is kept until the person is erased."
    if runs_at is None:
        when = "each time the clean-up runs (your operator schedules it)"
    else:
        when = f"each day at {runs_at.at:%H:%M} ({runs_at.zone})"
    return (
        f"Episodes older than {days_words(days)} are removed {when}; what the robot learned "
        "from them is kept."
    )


# -- what if: evaluations of other learners, in words -------------------------------------------
# Everything below reads an evaluation as GET /v1/admin/fleets/{fleet}/evaluations/{id} gives it
# (``app.services.evaluation_jobs.out``): plain dicts, the result's numbers untouched.

CANDIDATE_CHOICES: tuple[tuple[str, str, str], ...] = (
    # (form field, candidate as ``attune evaluate --candidate`` reads it, the words staff read)
    ("pick-dts", "dts", "DTS"),
    ("pick-hri-less", "hri:tau=0.005", "HRI, explores less (τ = 0.005)"),
    ("pick-hri-more", "hri:tau=0.1", "HRI, explores more (τ = 0.1)"),
    ("pick-qlearning", "qlearning", "Q-learning"),
    ("pick-rmax", "rmax", "R-MAX"),
    ("pick-dts-adapt", "dts-adapt", "DTS-adapt, follows a changed wish quickly"),
    ("pick-dts-routine", "dts-routine", "DTS-routine, follows each person's routine"),
)
"""The learners the console's forms offer to try, in the order they list them."""
WHAT_IF_CHOICES: tuple[tuple[str, str, str], ...] = (
    *CANDIDATE_CHOICES,
    ("pick-prior-on", "current:prior=on", "The current learners, newcomers from the fleet's prior"),
    ("pick-prior-off", "current:prior=off", "The current learners, without the fleet's prior"),
)
"""The What if form's: the learners, and the fleet's prior on or off."""

_JOB_STATUS = {
    "queued": "Waiting to start",
    "running": "Running",
    "done": "Done",
    "failed": "Did not finish",
    "cancelled": "Cancelled",
}
_ESTIMATOR_WORDS = {
    "wpdis": "weighted per-decision importance sampling (wpdis)",
    "pdis": "per-decision importance sampling (pdis)",
    "dr": "doubly robust (dr)",
    "wdr": "weighted doubly robust (wdr)",
}
_FEW = re.compile(r"not enough evidence: ([0-9]+) episodes, effective size ([0-9.]+)")


def signed(value: float) -> str:
    """A difference as the verdicts write it: "+0.39", "−0.40" (a true minus sign); a tiny
    difference either way is "+0.00"."""
    return f"{round(value, 2) + 0.0:+.2f}".replace("-", "−")


def per_encounter(value: float | None) -> str:
    """An amount earned per encounter: "2.17", "−0.40"."""
    return DASH if value is None else f"{round(value, 2) + 0.0:.2f}".replace("-", "−")


def job_active(job: dict[str, Any]) -> bool:
    """The evaluation is still to run or running (the page keeps refreshing)."""
    return job["status"] in ("queued", "running")


def job_status(job: dict[str, Any]) -> str:
    """An evaluation's state in words: "Running: 3 of 40 people", "Cancelled"."""
    status = str(job["status"])
    done, total = job["progress"]["people_done"], job["progress"]["people_total"]
    if status == "running" and job["cancel_requested"]:
        return "Stopping: cancel was asked, it stops after the person in hand"
    if status == "running":
        return f"Running: {done} of {total} people" if total else "Running"
    if status == "queued" and job["cancel_requested"]:
        return "Cancelled"
    return _JOB_STATUS.get(status, status)


def period_words(since: str | None, until: str | None, zone: str) -> str:
    """The period an evaluation counted, in the fleet's time zone: "all the history kept", "the
    episodes from 2026-11-01 00:00 until 2026-12-01 00:00"."""
    if since is None and until is None:
        return "all the history kept"
    parts = []
    if since is not None:
        parts.append(f"from {fmt_zone(dt.datetime.fromisoformat(since), zone)}")
    if until is not None:
        parts.append(f"until {fmt_zone(dt.datetime.fromisoformat(until), zone)}")
    return "the episodes " + " ".join(parts)


def verdict_kind(candidate: dict[str, Any]) -> str:
    """``more``, ``less``, ``same`` (the difference's interval holds 0) or ``unknown`` (not
    enough evidence): the look of a candidate's sentence."""
    difference = candidate.get("difference")
    if not candidate.get("enough") or difference is None:
        return "unknown"
    if difference["low"] > 0.0:
        return "more"
    if difference["high"] < 0.0:
        return "less"
    return "same"


def sentence(text: str) -> str:
    """The service's words as a sentence: a capital first, a full stop last."""
    text = cap(text.strip())
    return text if text.endswith((".", "!", "?")) else text + "."


def evidence_why(label: str, reason: str) -> str:
    """Why there is not enough evidence for ``label``, in staff words (the estimator's own
    reason, with its figures, is under "How this was estimated")."""
    if _FEW.match(reason):
        return (
            f"too few of the robots' encounters show what {label} would have done to say what "
            "it would earn"
        )
    if "rarely show" in reason:
        return (
            f"the robots seldom did what {label} would do, so their logs cannot say what it "
            "would earn"
        )
    if "never show" in reason:
        return f"{label} would often do what the robots never do there, which the logs cannot show"
    if "own model expects" in reason:
        return (
            f"{label} expects more (or less) of these encounters than the robots ever earned, "
            "so this way of estimating cannot lean on what it expects; the usual way may answer"
        )
    if "wider than the range" in reason:
        return f"the estimate for {label} is too uncertain to place it anywhere"
    if "what the robots earn now" in reason:
        return "too few episodes to tell what the robots earn now"
    return reason.removeprefix("not enough evidence: ")


def not_enough_words(candidate: dict[str, Any]) -> str:
    """ "DTS: not enough evidence: 125 episodes, effective size 44." """
    estimate = candidate["estimate"]
    ess = estimate.get("ess")
    size = DASH if ess is None else f"{ess:.1f}"
    return (
        f"{candidate['label']}: not enough evidence: {estimate['n_episodes']:,} episodes, "
        f"effective size {size}."
    )


@dataclass(frozen=True, slots=True)
class PersonWords:
    """One candidate for one person: ``kind`` as :func:`verdict_kind`, the difference with what
    the robots earned with them (None: not enough evidence), and the sentence."""

    kind: str
    difference: float | None
    words: str


def person_words(who: str, candidate: dict[str, Any], row: dict[str, Any]) -> PersonWords:
    """What ``candidate`` would have earned with one person, from that person's episodes alone
    (their row of the result), in words. Only their own episodes speak here, each candidate's
    interval against the robots' own with them: "likely more" when the two do not overlap."""
    label = candidate["label"]
    n = row["episodes"]
    mine = row["candidates"].get(candidate["key"])
    logged = row["logged"]
    encounters = f"from {n:,} of {who}'s encounters"
    if (
        mine is None
        or not mine["enough"]
        or not logged["enough"]
        or mine["value"] is None
        or logged["value"] is None
        or mine["interval"] is None
        or logged["interval"] is None
    ):
        return PersonWords(
            "unknown",
            None,
            f"For {who}, {label}: not enough evidence from {who}'s encounters alone "
            f"({n:,} counted).",
        )
    difference = mine["value"] - logged["value"]
    span = f"{signed(difference)} per encounter ({encounters})"
    if mine["interval"]["low"] > logged["interval"]["high"]:
        return PersonWords(
            "more",
            difference,
            f"For {who}, {label} would likely earn more than what the robots do now: {span}.",
        )
    if mine["interval"]["high"] < logged["interval"]["low"]:
        return PersonWords(
            "less",
            difference,
            f"For {who}, {label} would likely earn less than what the robots do now: {span}.",
        )
    return PersonWords(
        "same",
        difference,
        f"For {who}, {label} would earn about the same as what the robots do now, as far as "
        f"{who}'s encounters alone can tell: {span}.",
    )


def learners_words(learners: dict[str, int]) -> str:
    """The learners the robots use now, by how many people: "HRI with 38 people, DTS with 2"."""
    parts = []
    for i, (algorithm, n) in enumerate(sorted(learners.items(), key=lambda kv: -kv[1])):
        name = CandidateSpec(algorithm).label
        who = ("1 person" if n == 1 else f"{n:,} people") if i == 0 else f"{n:,}"
        parts.append(f"{name} with {who}")
    return ", ".join(parts)


def estimator_words(estimator: str) -> str:
    return _ESTIMATOR_WORDS.get(estimator, estimator)


# The plot: each learner's amount per encounter (a dot) and its interval (a bar), one row each,
# beside a line at what the robots earn now. Drawn on the server as SVG (no script, no style
# attribute: the pages' CSP), in a 720-wide box the page scales.
PLOT_WIDTH = 720
_PLOT_LEFT = 230  # the labels' column
_PLOT_RIGHT = 700
_PLOT_TOP = 28
_PLOT_ROW = 40


@dataclass(frozen=True, slots=True)
class PlotRow:
    label: str
    kind: str  # "now" | "more" | "less" | "same" | "unknown"
    y: float
    x: float | None
    low: float | None
    high: float | None
    value: float | None  # what it says (per encounter)


@dataclass(frozen=True, slots=True)
class PlotTick:
    x: float
    text: str


@dataclass(frozen=True, slots=True)
class Plot:
    width: int
    height: int
    left: int
    right: int
    top: int
    bottom: int
    now_x: float | None
    now_anchor: str  # where the line's label sits: "middle", or "end"/"start" near an edge
    rows: tuple[PlotRow, ...]
    ticks: tuple[PlotTick, ...]


def _step(span: float) -> float:
    raw = span / 5.0
    power = 10.0 ** math.floor(math.log10(raw)) if raw > 0 else 1.0
    for m in (1.0, 2.0, 2.5, 5.0, 10.0):
        if raw <= m * power:
            return m * power
    return 10.0 * power


def evaluation_plot(result: dict[str, Any]) -> Plot:
    """The plot of a finished evaluation: what the robots earn now (a dot, and the dashed line
    the others are read against), then each learner: a dot at what it would earn, and a bar
    that is what the robots earn now plus the interval of the difference, so that a bar that
    stays on one side of the line is exactly a "likely more" or "likely less" of the words (the
    difference's interval is narrower than either estimate's own: the same people count for
    both)."""
    logged = result["logged"]
    now = logged["value"]
    entries: list[tuple[str, str, float | None, float | None, float | None]] = [
        ("What the robots do now", "now", now, None, None)
    ]
    for c in result["candidates"]:
        kind = verdict_kind(c)
        value, difference = c["estimate"]["value"], c["difference"]
        if kind == "unknown" or value is None or now is None or difference is None:
            entries.append((c["label"], "unknown", None, None, None))
        else:
            entries.append(
                (c["label"], kind, value, now + difference["low"], now + difference["high"])
            )
    numbers = [v for _, _, *vs in entries for v in vs if v is not None]
    lo, hi = (min(numbers), max(numbers)) if numbers else (0.0, 1.0)
    if hi - lo < 0.2:  # a scale of at least a fifth of a reward
        middle = (hi + lo) / 2
        lo, hi = middle - 0.1, middle + 0.1
    pad = (hi - lo) * 0.08
    lo, hi = lo - pad, hi + pad
    step = _step(hi - lo)
    first = math.ceil(lo / step) * step
    left, right = _PLOT_LEFT, _PLOT_RIGHT

    def x_of(v: float) -> float:
        return round(left + (v - lo) / (hi - lo) * (right - left), 1)

    ticks = []
    t = first
    while t <= hi + 1e-9:
        ticks.append(PlotTick(x_of(t), per_encounter(t)))
        t += step
    rows = []
    for i, (label, kind, value, low, high) in enumerate(entries):
        y = _PLOT_TOP + _PLOT_ROW * i + _PLOT_ROW / 2
        rows.append(
            PlotRow(
                label,
                kind,
                y,
                None if value is None else x_of(value),
                None if low is None else x_of(low),
                None if high is None else x_of(high),
                value,
            )
        )
    bottom = _PLOT_TOP + _PLOT_ROW * len(entries)
    now_x = None if now is None else x_of(now)
    return Plot(
        width=PLOT_WIDTH,
        height=bottom + 36,
        left=left,
        right=right,
        top=_PLOT_TOP,
        bottom=bottom,
        now_x=now_x,
        now_anchor=(
            "end"
            if now_x is not None and now_x > right - 80
            else "start"
            if now_x is not None and now_x < left + 80
            else "middle"
        ),
        rows=tuple(rows),
        ticks=tuple(ticks),
    )


# -- rollout: a candidate learner tried without acting (a shadow), then on some of the people ---
# Everything below reads a shadow or a rollout as GET /v1/admin/fleets/{fleet}/shadow and
# .../rollout give them (``app.services.shadows`` and ``app.services.rollouts``): plain dicts.

ROLLOUT_DONE = {
    "shadow-started": "It has started. It decides beside the robots once each encounter of the "
    "people it follows has ended, and says below how often it would have done what the robots "
    "did. Nothing changes for anyone.",
    "shadow-stopped": "Stopped. What it decided so far stays below; it never acted.",
    "started": "The rollout has started. The people it gives the new learner are served by it "
    "from their next encounter on, keeping what the robots learned with them.",
    "share": "The percentage is changed.",
    "promoted": "Promoted. Everyone of the rollout gets the new learner, keeping what the robots "
    "learned with them, and so does everyone the robots meet for the first time from now on.",
    "rolled-back": "Rolled back. The people the new learner served get the learner they had "
    "before again, taught everything they did meanwhile.",
}
"""The notice at the top of the rollout page after each action (``?done=``)."""


def percent(share: float) -> str:
    """A share of people as a percentage: 0.2 -> "20%", 0.125 -> "12.5%"."""
    value = round(share * 100, 2)
    return f"{value:g}%"


def percent_field(share: float) -> str:
    """A share as the percentage field shows it: 0.2 -> "20"."""
    return f"{round(share * 100, 2):g}"


def people_words(n: int) -> str:
    """ "1 person", "12 people", "1,024 people"."""
    return "1 person" if n == 1 else f"{n:,} people"


def fmt_day(at: dt.datetime | None, zone: str, today: dt.date | None = None) -> str:
    """A day as people say it, in the fleet's time zone: "4 Dec" (this year), "4 Dec 2025"."""
    if at is None:
        return DASH
    if at.tzinfo is None:
        at = at.replace(tzinfo=dt.UTC)
    local = at.astimezone(zoneinfo.ZoneInfo(zone))
    now = today or dt.datetime.now(zoneinfo.ZoneInfo(zone)).date()
    day = f"{local.day} {local:%b}"
    return day if local.year == now.year else f"{day} {local.year}"


def who_did(key_id: str | None, names: dict[str, str]) -> str:
    """Who started or ended a shadow or a rollout: the key's name, "the guard", or "a key"."""
    if key_id is None:
        return "someone"
    if key_id == "guard":
        return "the guard"
    return key_label(key_id, names)


def shadow_status_words(shadow: dict[str, Any], names: dict[str, str], zone: str) -> str:
    """ "Running since 2026-12-07 04:00 (started by night-shift), for 100% of the people." """
    by = who_did(shadow["started_by"], names)
    started = f"{fmt_zone(shadow['started_at'], zone)} (started by {by})"
    if shadow["status"] == "running":
        return f"Running since {started}, for {percent(shadow['share'])} of the people."
    return (
        f"Stopped on {fmt_zone(shadow['stopped_at'], zone)} by "
        f"{who_did(shadow['stopped_by'], names)}; it ran from {started}, for "
        f"{percent(shadow['share'])} of the people."
    )


def shadow_words(shadow: dict[str, Any]) -> tuple[str, str | None]:
    """A shadow's look in the staff's words: how often it would have done what the robots did
    (the service's sentence), and what its newest estimate says it would earn, as the What if
    page says it (None before the first estimate)."""
    summary = str(shadow.get("agreement_summary") or shadow["summary"])
    estimate = shadow.get("estimate") or {}
    found = estimate.get("candidates") or []
    if not found:
        return summary, None
    candidate = found[0]
    verdict = str(candidate.get("verdict") or "")
    label = shadow["candidate"]["label"]
    if candidate.get("enough") and verdict:
        said = sentence(verdict)
    else:
        why = evidence_why(label, str(candidate.get("reason") or verdict))
        said = f"Not enough evidence yet to say what {label} would earn: {why}."
    episodes = int(estimate.get("episodes") or 0)
    counted = "1 encounter" if episodes == 1 else f"{episodes:,} encounters"
    return summary, f"{said} (From the {counted} since it started.)"


GUARD_PREFIX = "the guard: "


def rollout_status_words(rollout: dict[str, Any], names: dict[str, str], zone: str) -> str:
    """Where a rollout stands, in a sentence: running, promoted by whom, rolled back by whom
    (by the guard: said so, with its reason)."""
    label = rollout["candidate"]["label"]
    started = f"{fmt_zone(rollout['started_at'], zone)} by {who_did(rollout['started_by'], names)}"
    status = rollout["status"]
    if status == "running":
        return f"Running since {started}, for {percent(rollout['share'])} of the people."
    ended = fmt_zone(rollout["ended_at"], zone)
    if status == "promoted":
        return (
            f"Promoted on {ended} by {who_did(rollout['ended_by'], names)}: {label} serves "
            f"everyone of the rollout, and everyone the robots meet for the first time since. "
            f"It was started {started}."
        )
    reason = (rollout.get("end_reason") or "").strip()
    if rollout["ended_by"] == "guard":
        because = reason.removeprefix(GUARD_PREFIX)
        said = f", because {because}" if because else "."
        if said != "." and not said.endswith((".", "!", "?")):
            said += "."
        return f"Rolled back automatically by the guard on {ended}{said}"
    who = who_did(rollout["ended_by"], names)
    if reason:
        return f"Rolled back on {ended} by {who}, who said why: “{reason}”"
    return f"Rolled back on {ended} by {who}."


def moving_words(rollout: dict[str, Any]) -> str | None:
    """The people still to move to the learner their group gives them (a person at a time, in
    the background), in a sentence; None when nobody is."""
    n = int(rollout.get("moving") or 0)
    if not n:
        return None
    label = rollout["candidate"]["label"]
    who = "1 person is" if n == 1 else f"{n:,} people are"
    where = "back to the learner they had" if rollout["status"] == "rolled_back" else f"to {label}"
    return (
        f"{who} still being moved {where}, one person at a time, keeping what the robots "
        "learned with them: it takes seconds (reload the page)."
    )


def rollout_kind(comparison: dict[str, Any]) -> str:
    """``more``, ``less``, ``same`` or ``unknown`` (not enough evidence): the look of the
    comparison's sentence and plot, as the What if verdicts'."""
    if not comparison.get("enough") or comparison.get("difference") is None:
        return "unknown"
    if comparison["verdict"] == "better":
        return "more"
    if comparison["verdict"] == "worse":
        return "less"
    return "same"


def rollout_arm_words(arm: RolloutArmOut, zone: str) -> str:
    """A person's arm in a rollout (``ProfileOut.rollout``), in a line for their header: "In
    the rollout of HRI τ=0.005: served by the candidate since 4 Dec"."""
    label = arm.candidate.get("label") or arm.candidate.get("key", "")
    day = fmt_day(arm.assigned_at, zone)
    candidate = arm.arm == "candidate"
    if arm.moving:
        if arm.rollout_status == "rolled_back":
            return (
                f"The rollout of {label} was rolled back: being moved back to the learner they "
                "had before."
            )
        return f"In the rollout of {label}: being moved to {label}, keeping what was learned."
    if arm.rollout_status == "running":
        if candidate:
            return f"In the rollout of {label}: served by the candidate since {day}."
        return f"In the rollout of {label}: keeps the current learner."
    if arm.rollout_status == "promoted":
        if candidate:
            return f"Served by {label} since {day}: its rollout was promoted."
        return f"Served by {label}: its rollout was promoted."
    if candidate:
        return (
            f"Was served by {label} from {day} until its rollout was rolled back: back on the "
            "learner they had before."
        )
    return f"Kept the current learner during the rollout of {label}, which was rolled back."


@dataclass(frozen=True, slots=True)
class RolloutPlot:
    """The comparison drawn: the difference (a dot) and its interval (a bar) against no
    difference (a dashed line at 0), in a box ``width`` wide."""

    width: int
    height: int
    left: int
    right: int
    y: float
    kind: str  # "more" | "less" | "same"
    zero_x: float
    zero_anchor: str
    x: float
    low: float
    high: float
    difference: float
    ticks: tuple[PlotTick, ...]


def rollout_plot(comparison: dict[str, Any]) -> RolloutPlot | None:
    """The plot of a look at a rollout's arms, or None without enough evidence."""
    found = [comparison.get(k) for k in ("difference", "low", "high")]
    numbers = [float(v) for v in found if isinstance(v, (int, float)) and math.isfinite(v)]
    if rollout_kind(comparison) == "unknown" or len(numbers) != 3:
        return None
    difference, low, high = numbers
    lo, hi = min(0.0, low, difference), max(0.0, high, difference)
    if hi - lo < 0.2:
        middle = (hi + lo) / 2
        lo, hi = middle - 0.1, middle + 0.1
    pad = (hi - lo) * 0.08
    lo, hi = lo - pad, hi + pad
    step = _step(hi - lo)
    left, right = 40, 680

    def x_of(v: float) -> float:
        return round(left + (v - lo) / (hi - lo) * (right - left), 1)

    ticks = []
    t = math.ceil(lo / step) * step
    while t <= hi + 1e-9:
        ticks.append(PlotTick(x_of(t), "0" if abs(t) < step / 1000 else signed(t)))
        t += step
    zero_x = x_of(0.0)
    return RolloutPlot(
        width=PLOT_WIDTH,
        height=112,
        left=left,
        right=right,
        y=44.0,
        kind=rollout_kind(comparison),
        zero_x=zero_x,
        zero_anchor="end" if zero_x > right - 60 else "start" if zero_x < left + 60 else "middle",
        x=x_of(difference),
        low=x_of(low),
        high=x_of(high),
        difference=difference,
        ticks=tuple(ticks),
    )
