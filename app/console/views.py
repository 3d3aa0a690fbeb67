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
from collections.abc import Sequence
from dataclasses import dataclass
from urllib.parse import quote, urlencode

from app.learning import Mission
from app.schemas.common import ActionOut
from app.schemas.models import ActionBelief, ContextModel, ModelOut, StateModel
from app.schemas.profile import CorrectionOut, ProfileContext, ProfileOut, RobotWill, Wanted
from app.schemas.users import UserOut

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
def user_url(user: UserOut, tail: str = "", **params: object) -> str:
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


def correction_words(c: CorrectionOut) -> str:
    """What a correction says: "Prefers Provide drink (tea)", "Avoid Brief information",
    "Quiet: the robot does not offer help"."""
    if c.kind == "prefers":
        return f"Prefers {wanted_words(None, service=c.service, detail=c.detail)}"
    if c.kind == "avoid":
        return f"Do not offer {wanted_words(None, service=c.service, detail=c.detail)}"
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
