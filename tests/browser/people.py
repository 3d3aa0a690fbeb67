"""Scripted people and robots that fill a live service with history through the v1 API, and the
console's documented number formats, to compare what a page shows with what the API returns."""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field
from typing import Any

import httpx

from tests.support import episodes, people
from tests.support.episodes import play

HOURS = {"morning": 9, "noon": 12, "afternoon": 15, "evening": 19}  # local hours inside each slot
SITUATIONS = ("arriving", "working", "stretching", "busy")
DETAILS = {
    "ProvideDrink": ("tea", "coffee", "water"),
    "BriefInformation": ("news", "weather", "stocks"),
    "ArrangeSchedule": ("today_agenda", "next_meeting", "set_reminder"),
}


@dataclass
class Person:
    """What a person wants where (time slot, situation) -> (service, detail), and how they react:
    they accept offers where they have a need (but never while busy), answer questions truthfully,
    accept the right service (with a little noise), sometimes ask first, sometimes smile after."""

    needs: dict[tuple[str, str], tuple[str, str]]
    rnd: random.Random = field(default_factory=lambda: random.Random(7))

    def event(self) -> tuple[str, str]:
        if self.needs and self.rnd.random() < 0.7:
            return self.rnd.choice(sorted(self.needs))
        return self.rnd.choice(sorted(HOURS)), self.rnd.choice(SITUATIONS)

    def at(self, context: tuple[str, str]) -> episodes.Person:
        """The person in ``context`` (time slot, situation), as ``play`` takes one."""
        return people.person(
            need=self.needs.get(context),
            busy=context[1] == "busy",
            rng=self.rnd,
            yes=0.95,
            asks=0.5,
            smiles=0.3,
        )


def meet(client: httpx.Client, user_id: str, person: Person, episodes: int, *, prefix: str) -> None:
    """``episodes`` events of ``person`` through the API, each until it closes; now and then the
    person addresses the robot first, and now and then frowns after."""
    for n in range(episodes):
        slot, situation = person.event()
        need = person.needs.get((slot, situation))
        human = need is not None and situation != "busy" and person.rnd.random() < 0.15
        played = play(
            client,
            user_id,
            f"{prefix}-{n}",
            person.at((slot, situation)),
            situation=situation,
            occurred_at=f"2026-11-{1 + n // 24:02d}T{HOURS[slot]:02d}:{n % 60:02d}:00+08:00",
            initiator="human" if human else "robot",
            request={"service": need[0], "detail": need[1]} if human and need is not None else None,
        )
        if person.rnd.random() < 0.1:
            r = client.post(
                f"/v1/episodes/{played.episode_id}/feedback",
                json={"feedback_id": f"{prefix}-fb-{n}", "feedback": "negative"},
            )
            assert r.status_code == 200, r.text


# -- the console's number formats, as its pages document them ---------------------------------
def pct(p: float | None, digits: int = 1) -> str:
    return "—" if p is None else f"{p * 100:.{digits}f}%"


def two(x: float | None) -> str:
    return "—" if x is None else f"{x:.2f}"


def one(x: float | None) -> str:
    return "—" if x is None else f"{x:.1f}"


def count(v: float | None) -> str:
    if v is None:
        return "—"
    return str(int(v)) if float(v).is_integer() else f"{v:.2f}"


def measure(m: float | None) -> str:
    return "—" if m is None else f"{m:.3g}"


def action_label(action: dict[str, Any]) -> str:
    kind = action["kind"]
    if kind == "infer_detail":
        return f"{kind}({action['detail']})"
    if kind in ("respond", "infer_type", "query_detail"):
        return f"{kind}({action['service']})"
    return str(kind)


def state_label(state: dict[str, Any]) -> str:
    parts = [p for p in (state.get("service"), state.get("detail")) if p]
    return f"{state['state']}({', '.join(parts)})" if parts else str(state["state"])


def find_state(
    context: dict[str, Any], kind: str, service: str | None = None
) -> dict[str, Any] | None:
    for s in context["states"]:
        if s["state"] == kind and (service is None or s.get("service") == service):
            return s  # type: ignore[no-any-return]
    return None


def top(actions: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The most probable action, None on a tie for first place."""
    ranked = sorted(actions, key=lambda a: a["p"], reverse=True)
    if not ranked or (
        len(ranked) > 1
        and math.isclose(ranked[0]["p"], ranked[1]["p"], rel_tol=1e-9, abs_tol=1e-12)
    ):
        return None
    return ranked[0]


def expected_cell(context: dict[str, Any]) -> dict[str, str]:
    """What a heatmap cell must show for a context of GET /model (the console's documented
    reading of the policy: P(initiate); the type and detail it would guess once engaged; the
    chance it performs that without asking; the chance it asks first)."""
    observe = find_state(context, "OBSERVE")
    assert observe is not None
    out = {
        "p-init": pct(
            next(a["p"] for a in observe["actions"] if a["action"]["kind"] == "initiate"), 0
        ),
        "episodes": str(sum(a["visits"] for a in observe["actions"])),
    }
    engaged = find_state(context, "ENGAGED")
    assert engaged is not None
    ever = any(
        a["visits"] > 0 for s in context["states"] if s["state"] != "OBSERVE" for a in s["actions"]
    )
    if not ever:
        out["expect"] = "no mission yet"
        return out
    ask = sum(a["p"] for a in engaged["actions"] if a["action"]["kind"] == "query_type")
    guesses = []
    for g in engaged["actions"]:
        if g["action"]["kind"] != "infer_type":
            continue
        known = find_state(context, "TYPE_KNOWN", g["action"]["service"])
        assert known is not None
        for a in known["actions"]:
            if a["action"]["kind"] == "query_detail":
                ask += g["p"] * a["p"]
            else:
                guesses.append(
                    {
                        "p": g["p"] * a["p"],
                        "service": g["action"]["service"],
                        "detail": a["action"]["detail"],
                    }
                )
    out["p-ask"] = pct(ask, 0)
    best = top(guesses)
    if best is None:
        out["service"] = "no preference yet"
        return out
    out.update(service=best["service"], detail=best["detail"], **{"p-guess": pct(best["p"], 0)})
    return out
