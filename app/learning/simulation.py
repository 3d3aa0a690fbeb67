"""Simulated users (docs/method.md §11): seeded, with common random numbers across methods.

A user has 3-5 *need rules*: in context (time slot, situation) they want service k, detail d.
Events come as a stream generated up front (so every method sees the same events); the user's
coin flips come from a table of uniforms indexed (event, step), so identical situations get
identical flips across methods. ``drift`` changes about half of the rules, as the users of the
paper's second experiment did.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from .mission import Mission
from .negotiation import EXPECTS, Response, outcome
from .space import ActionKind, NegotiationSpace
from .types import IntArray, Polarity

__all__ = [
    "Need",
    "Reaction",
    "UserProfile",
    "drift",
    "event_stream",
    "random_profile",
    "respond",
]

STEP_COLUMNS = 8  # uniforms per event: two per visible step, and an episode has at most four


@dataclass(frozen=True, slots=True)
class Need:
    """In ``context`` the user wants ``service`` / ``detail`` (indices into the mission)."""

    context: int
    service: int
    detail: int


@dataclass(frozen=True, slots=True)
class UserProfile:
    """A simulated person: need rules plus response parameters (defaults of docs/method.md §11)."""

    needs: tuple[Need, ...]
    p_acc: float = 0.95  # accepts an initiation when a need exists
    p_self: float = 0.5  # initiates after the robot passed, when a need exists
    eps_fb: float = 0.05  # rejects the right service as noise
    p_abort: float = 0.0  # ends the dialog at any step
    p_idle_acc: float = 0.0  # accepts an initiation without a need

    def __post_init__(self) -> None:
        for name in ("p_acc", "p_self", "eps_fb", "p_abort", "p_idle_acc"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {value!r}.")
        contexts = [n.context for n in self.needs]
        if len(set(contexts)) != len(contexts):
            raise ValueError("needs must have distinct contexts.")

    def need_at(self, context: int) -> Need | None:
        for need in self.needs:
            if need.context == context:
                return need
        return None


def _available_contexts(mission: Mission) -> list[int]:
    return [
        c
        for c in range(mission.n_contexts)
        if mission.context_names(c)[1] not in mission.unavailable_situations
    ]


def random_profile(
    mission: Mission, rng: np.random.Generator, *, n_needs: Sequence[int] = (3, 4, 5)
) -> UserProfile:
    """A user with a random number of need rules in distinct contexts where service is welcome."""
    available = _available_contexts(mission)
    n = int(rng.choice(np.asarray(n_needs)))
    contexts = rng.choice(np.asarray(available), size=min(n, len(available)), replace=False)
    needs = []
    for c in contexts:
        k = int(rng.integers(len(mission.services)))
        d = int(rng.integers(len(mission.services[k].details)))
        needs.append(Need(int(c), k, d))
    return UserProfile(tuple(needs))


def drift(profile: UserProfile, mission: Mission, rng: np.random.Generator) -> UserProfile:
    """Change ceil(n/2) rules: a new detail (p 0.5), a new service (0.3) or a new context (0.2)."""
    needs = list(profile.needs)
    chosen = rng.choice(len(needs), size=math.ceil(len(needs) / 2), replace=False)
    for i in sorted(int(x) for x in chosen):
        need = needs[i]
        u = rng.random()
        details = mission.services[need.service].details
        if u < 0.5 and len(details) > 1:
            others = [d for d in range(len(details)) if d != need.detail]
            needs[i] = replace(need, detail=int(rng.choice(others)))
        elif u < 0.8 and len(mission.services) > 1:
            others = [k for k in range(len(mission.services)) if k != need.service]
            k = int(rng.choice(others))
            needs[i] = replace(
                need, service=k, detail=int(rng.integers(len(mission.services[k].details)))
            )
        else:
            used = {n.context for n in needs}
            free = [c for c in _available_contexts(mission) if c not in used]
            if free:
                needs[i] = replace(need, context=int(rng.choice(free)))
    return replace(profile, needs=tuple(needs))


def event_stream(
    profiles: Sequence[UserProfile],
    change_points: Sequence[int],
    mission: Mission,
    n_events: int,
    rng: np.random.Generator,
    *,
    p_need: float = 0.7,
) -> IntArray:
    """Contexts of ``n_events`` events; ``profiles[i]`` is in force from event ``change_points[i]``.

    With ``p_need`` the event falls in one of the user's current need contexts (uniformly),
    otherwise in a uniform context without a need (unavailable situations included).
    """
    if not change_points or change_points[0] != 0 or list(change_points) != sorted(change_points):
        raise ValueError("change_points must start at 0 and increase (one per profile).")
    if len(change_points) != len(profiles):
        raise ValueError("give one change point per profile.")
    out = np.empty(n_events, dtype=np.int64)
    for e in range(n_events):
        profile = profiles[sum(1 for cp in change_points if cp <= e) - 1]
        need_contexts = [n.context for n in profile.needs]
        others = [c for c in range(mission.n_contexts) if c not in need_contexts]
        # Same draws as before; a mission whose every context holds a need has no "other" one.
        if (rng.random() < p_need or not others) and need_contexts:
            out[e] = need_contexts[int(rng.integers(len(need_contexts)))]
        else:
            out[e] = others[int(rng.integers(len(others)))]
    return out


@dataclass(frozen=True, slots=True)
class Reaction:
    """What the simulated person did (the API's response word, and the service or detail they
    named, if any) and what it meant."""

    response: Response
    reward: float
    next_state: int
    signal: Polarity
    service: str | None = None
    detail: str | None = None


def respond(
    space: NegotiationSpace,
    profile: UserProfile,
    context: int,
    state: int,
    action: int,
    uniforms: np.ndarray,
) -> Reaction:
    """The person's reaction to a visible action (docs/method.md §2 and §11).

    ``uniforms`` are two numbers in [0, 1): the first decides the reaction, the second an abort.
    The person chooses the response; what it means (reward, next state) is the negotiation's
    rule, :func:`app.learning.negotiation.outcome`.
    """
    mission = space.mission
    need = profile.need_at(context)
    kind = space.actions[action].kind
    if kind not in EXPECTS:
        raise ValueError(
            f"{space.action_name(action)} is silent: the person does not respond to it."
        )
    service: str | None = None
    detail: str | None = None
    # The person may end the dialog at any step; a robot that stays passive starts no dialog.
    if kind is not ActionKind.PASS and profile.p_abort > 0.0 and uniforms[1] < profile.p_abort:
        said = Response.TERMINATED
    else:
        u = uniforms[0]
        available = mission.context_names(context)[1] not in mission.unavailable_situations
        wanted = mission.services[need.service] if need is not None else None
        info = space.states[state]
        if kind is ActionKind.INITIATE:
            p = profile.p_acc if need is not None else profile.p_idle_acc
            said = Response.ACCEPTED if available and u < p else Response.REJECTED
        elif kind is ActionKind.PASS:
            # docs/method.md §11: busy (an unavailable situation): never speaks first.
            if wanted is not None and available and u < profile.p_self:
                said, service = Response.HUMAN_REQUEST, wanted.name
            else:
                said = Response.NONE
        elif kind is ActionKind.QUERY_TYPE:
            if wanted is None:
                said = Response.TERMINATED
            else:
                said, service = Response.ANSWERED, wanted.name
        elif kind is ActionKind.QUERY_DETAIL:
            if wanted is None or wanted.name != info.service:
                said = Response.TERMINATED
            else:
                assert need is not None
                said, detail = Response.ANSWERED, wanted.details[need.detail]
        else:  # perform
            right = (
                wanted is not None
                and need is not None
                and info.service == wanted.name
                and info.detail == wanted.details[need.detail]
            )
            said = Response.ACCEPTED if right and u >= profile.eps_fb else Response.REJECTED
    result = outcome(space, action, said, service=service, detail=detail)
    return Reaction(said, result.reward, result.next_state, result.signal, service, detail)
