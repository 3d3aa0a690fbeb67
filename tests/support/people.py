"""What a person answers when a robot acts: the one policy of the tests and the benchmarks.

``answer(action, need=..., rng=...)`` gives the outcome's fields for one decision (``response``
and, where that response needs them, ``service`` and ``detail``; sometimes ``feedback``). The
action is the API's JSON (``{"kind", "service", "detail"}``) or the client's ``Action``.

The person wants ``need`` here (a (service, detail) pair of the office mission, or None:
nothing). By default the person is *picky*: accepts an offer only with a need and when not
``busy``; when the robot passes, asks for the need's service (chance ``asks``); answers a
question truthfully, or ends the talk when it is about something else; accepts only the service
it needs. With ``picky=False`` the person goes along with whatever the robot proposes: accepts
offers and any service, and asked about a service other than the need's, names that service's
first detail.

``yes`` is the chance of accepting what the person would accept, ``precise`` the chance that
a request names the detail too, ``smiles`` the chance of positive feedback on the right service.
A chance of 0 or 1 draws nothing from ``rng`` (answers without chances need no generator).

``person(...)`` is such a person as ``tests/support/episodes.py``'s ``play`` takes one: a
decision in, its answer out. ``cooperative(action, n)`` is the person of the client's tests:
one who goes along with the robot, whose answers vary with ``n`` and are always the same for
the same ``n``.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Mapping
from typing import Any

from app.learning import Mission

from .office import MISSION

Need = tuple[str, str]
TEA: Need = ("ProvideDrink", "tea")


def _fields(action: Any) -> tuple[str, str | None, str | None]:
    if isinstance(action, Mapping):
        return str(action["kind"]), action.get("service"), action.get("detail")
    return str(action.kind), action.service, action.detail


def answer(
    action: Any,
    *,
    need: Need | None = TEA,
    rng: random.Random | None = None,
    picky: bool = True,
    busy: bool = False,
    yes: float = 1.0,
    asks: float = 1.0,
    precise: float = 0.0,
    smiles: float = 0.0,
    mission: Mission = MISSION,
) -> dict[str, Any]:
    """The outcome fields a person with ``need`` gives to ``action`` (see the module), under
    ``mission`` (the service's: a non-picky person answers a question with its first
    detail)."""

    def chance(p: float) -> bool:
        if p >= 1.0 or p <= 0.0:
            return p >= 1.0
        if rng is None:
            raise ValueError(f"a chance of {p} needs rng")
        return rng.random() < p

    kind, service, detail = _fields(action)
    if kind == "initiate":
        willing = not picky or (need is not None and not busy)
        return {"response": "accepted" if willing and chance(yes) else "rejected"}
    if kind == "pass":
        if need is not None and chance(asks):
            out = {"response": "human_request", "service": need[0]}
            if chance(precise):
                out["detail"] = need[1]
            return out
        return {"response": "none"}
    if kind == "query_type":
        return (
            {"response": "answered", "service": need[0]}
            if need is not None
            else {"response": "terminated"}
        )
    if kind == "query_detail":
        if need is not None and service == need[0]:
            return {"response": "answered", "detail": need[1]}
        if picky or service is None:
            return {"response": "terminated"}
        return {"response": "answered", "detail": mission.service(service).details[0]}
    right = not picky or (need is not None and (service, detail) == need)
    out = {"response": "accepted" if right and chance(yes) else "rejected"}
    if right and chance(smiles):
        out["feedback"] = "positive"
    return out


def cooperative(action: Any, n: int = 0) -> dict[str, Any]:
    """What a cooperative person answers (``picky=False``): yes four times in five, a request
    for tea seven times in ten when the robot waits; ``n`` varies the answers a little (a
    person who says no, stays silent, or asks for something), the same for the same ``n``."""
    return answer(action, picky=False, rng=random.Random(n), yes=0.8, asks=0.7)


def person(**settings: Any) -> Callable[[dict[str, Any]], dict[str, Any]]:
    """The person ``answer(action, **settings)`` describes, as ``play`` takes one: a decision
    (the API's JSON) in, the outcome's fields out."""

    def answers(decision: dict[str, Any]) -> dict[str, Any]:
        return answer(decision["action"], **settings)

    return answers
