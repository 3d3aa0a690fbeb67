"""The rules of the service negotiation: what a person's response to a robot's action means.

One place for what the service, the simulated people, the experiments, the stats and the
console all need to agree on (docs/method.md §2 and §3):

- :data:`EXPECTS`: which responses each visible action allows;
- :func:`outcome`: the reward, the next state and the signal of a response;
- :func:`interaction`: the interaction class of an episode from its root step (eq. 1);
- :class:`Tally`: an episode's figures for the paper's metrics (initiated, class, success,
  queries, reward), kept as its steps are answered.

Pure functions of the mission's :class:`~app.learning.space.NegotiationSpace`; nothing here
knows about storage or HTTP.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from types import MappingProxyType
from typing import NamedTuple

from .mission import Rewards
from .space import ActionKind, NegotiationSpace
from .types import Interaction, Polarity, Transition

__all__ = [
    "EXPECTS",
    "INTERACTION_CODE",
    "Outcome",
    "Response",
    "Tally",
    "feedback_reward",
    "interaction",
    "interaction_class",
    "outcome",
]


class Response(StrEnum):
    """What the person did after a visible action."""

    ACCEPTED = "accepted"  # took the offer or the service
    REJECTED = "rejected"  # declined the offer or the service
    TERMINATED = "terminated"  # ended the dialog
    ANSWERED = "answered"  # answered a question (the service, or the detail)
    HUMAN_REQUEST = "human_request"  # the robot stayed passive and the person asked
    NONE = "none"  # the robot stayed passive and nothing happened


_R = Response
EXPECTS: Mapping[ActionKind, tuple[Response, ...]] = MappingProxyType(
    {
        ActionKind.INITIATE: (_R.ACCEPTED, _R.REJECTED, _R.TERMINATED),
        ActionKind.PASS: (_R.HUMAN_REQUEST, _R.NONE),
        ActionKind.QUERY_TYPE: (_R.ANSWERED, _R.TERMINATED),
        ActionKind.QUERY_DETAIL: (_R.ANSWERED, _R.TERMINATED),
        ActionKind.PERFORM: (_R.ACCEPTED, _R.REJECTED, _R.TERMINATED),
    }
)
"""The responses each visible action allows (silent actions take none)."""

INTERACTION_CODE: Mapping[Interaction, int] = MappingProxyType(
    {
        Interaction.NONE: 0,
        Interaction.I1: 1,
        Interaction.I2: 2,
        Interaction.I3: 3,
    }
)
"""Small integer codes of the classes, for tables of many episodes (0 is no interaction)."""


class Outcome(NamedTuple):
    """What a response means: the step's reward, the state it leads to, and its signal (the
    polarity of the person's reaction: accepted or answered positive, rejected or terminated
    negative, nothing neutral)."""

    reward: float
    next_state: int
    signal: Polarity


def outcome(
    space: NegotiationSpace,
    action: int,
    response: Response | str,
    *,
    service: str | None = None,
    detail: str | None = None,
) -> Outcome:
    """The transition and reward of ``response`` to the visible ``action`` (a pair index).

    ``service`` is the service the person named: with ``human_request`` (``None``: they spoke
    to the robot without naming one yet, which leads to ENGAGED) and when answering
    ``query_type``. ``detail`` is the detail named when answering ``query_detail`` (of the
    action's own service). Raises ``ValueError`` for a response the action does not allow or a
    name the mission does not have.
    """
    act = space.actions[action]
    kind = act.kind
    allowed = EXPECTS.get(kind)
    if allowed is None:
        raise ValueError(f"{space.action_name(action)} is silent: the person does not respond.")
    try:
        said = Response(response)
    except ValueError:
        said = None
    if said not in allowed:
        raise ValueError(
            f"response to {kind.value} must be one of {', '.join(allowed)}; got {response!r}."
        )
    rw = space.mission.rewards
    query = rw.query if space.is_query[action] else 0.0
    end = space.END
    if said in (Response.REJECTED, Response.TERMINATED):
        return Outcome(query + rw.negative, end, Polarity.NEGATIVE)
    if kind is ActionKind.INITIATE:  # accepted
        return Outcome(rw.positive, space.ENGAGED, Polarity.POSITIVE)
    if kind is ActionKind.PASS:
        if said is Response.NONE:
            return Outcome(0.0, end, Polarity.NEUTRAL)
        nxt = space.ENGAGED if service is None else _known(space.request_state, service)
        return Outcome(0.0, nxt, Polarity.POSITIVE)
    if kind is ActionKind.QUERY_TYPE:
        if service is None:
            raise ValueError("an answer to query_type names the service.")
        return Outcome(query, _known(space.type_known_state, service), Polarity.POSITIVE)
    if kind is ActionKind.QUERY_DETAIL:
        assert act.service is not None
        if detail is None:
            raise ValueError("an answer to query_detail names the detail.")
        nxt = _known(space.detail_known_state, act.service, detail)
        return Outcome(query, nxt, Polarity.POSITIVE)
    return Outcome(rw.positive + rw.accepted_service, end, Polarity.POSITIVE)  # perform taken


def _known(lookup: object, *names: str) -> int:
    try:
        return int(lookup(*names))  # type: ignore[operator]
    except (KeyError, ValueError):
        raise ValueError(f"{'/'.join(names)} is not in the mission.") from None


def feedback_reward(rewards: Rewards, feedback: str) -> float:
    """The reward of explicit feedback (a smile, a complaint): ``positive`` or ``negative``."""
    if feedback == "positive":
        return rewards.positive
    if feedback == "negative":
        return rewards.negative
    raise ValueError(f"feedback must be positive or negative; got {feedback!r}.")


def interaction(space: NegotiationSpace, root_action: int, next_state: int) -> Interaction:
    """Eq. (1), from an episode's root step: who initiated, and how it was taken.

    The robot initiated and was accepted: I2; initiated and was turned down: I3; stayed passive
    and the person spoke: I1; stayed passive and nothing happened: no interaction.
    """
    taken = next_state != space.END
    if root_action == space.INITIATE:
        return Interaction.I2 if taken else Interaction.I3
    return Interaction.I1 if taken else Interaction.NONE


def interaction_class(space: NegotiationSpace, rows: Sequence[Transition]) -> Interaction:
    """The class of an episode from its transitions (its root step, if present)."""
    for row in rows:
        if row.state == space.OBSERVE:
            return interaction(space, row.action, row.next_state)
    return Interaction.NONE


@dataclass(slots=True)
class Tally:
    """An episode's figures for the paper's metrics, updated as its steps happen.

    ``initiated``: the robot chose to initiate; ``interaction``: the class of eq. (1);
    ``success``: a performed service was accepted; ``queries``: questions asked;
    ``reward``: the total, silent steps and feedback included.
    """

    initiated: bool = False
    interaction: Interaction = Interaction.NONE
    success: bool = False
    queries: int = 0
    reward: float = 0.0

    def step(
        self,
        space: NegotiationSpace,
        state: int,
        action: int,
        reward: float,
        next_state: int,
        signal: Polarity = Polarity.NEUTRAL,
    ) -> None:
        """Count one executed step (silent ones too): its reward, where it led, and the signal
        of the person's response (silent steps have none)."""
        self.reward += reward
        self.queries += int(space.is_query[action])
        if state == space.OBSERVE:
            self.initiated = action == space.INITIATE
            self.interaction = interaction(space, action, next_state)
        if space.actions[action].kind is ActionKind.PERFORM and signal is Polarity.POSITIVE:
            self.success = True
