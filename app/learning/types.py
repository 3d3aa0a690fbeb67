"""Value types shared by the learners, the simulator and the service.

Indices, not names, travel through the hot path: a *context* is an index into the mission's
(time slot, situation) grid, a *state* is a local state index inside one context (the layout is
:class:`app.learning.space.NegotiationSpace`'s), and an *action* is a pair index, the position of
the (state, action) pair in the context's pair list. ``END`` is the absorbing terminal state.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, StrEnum

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "ChainStep",
    "ContextView",
    "Decision",
    "FloatArray",
    "IntArray",
    "Interaction",
    "Observation",
    "Polarity",
    "Transition",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


class Polarity(IntEnum):
    """The polarity of a human response or of a sample (docs/method.md §4); also an array index."""

    NEUTRAL = 0
    POSITIVE = 1
    NEGATIVE = 2


class Interaction(StrEnum):
    """Interaction class of an episode, eq. (1): who initiated and how it was taken."""

    NONE = "none"  # I0: nothing happened
    I1 = "I1"  # the human initiated
    I2 = "I2"  # the robot initiated and was accepted
    I3 = "I3"  # the robot initiated and was rejected


@dataclass(frozen=True, slots=True)
class Observation:
    """Where a decision is asked for: context, local state, and the user's 1-based episode index."""

    context: int
    state: int
    episode: int


@dataclass(frozen=True, slots=True)
class Transition:
    """One executed (state, action) pair and what followed.

    ``signal`` is the polarity of the human's response to this step (accepted or answered:
    positive; rejected or terminated: negative; no response: neutral). The signal of the step that
    ends the episode (``next_state == space.END``) is the episode's outcome polarity omega(e).
    """

    episode: int
    context: int
    state: int
    action: int
    reward: float
    next_state: int
    signal: Polarity = Polarity.NEUTRAL


@dataclass(frozen=True, slots=True)
class ChainStep:
    """A silent step taken by the robot itself on the way to a decision (respond, infer)."""

    state: int
    action: int
    probabilities: FloatArray
    next_state: int
    reward: float


@dataclass(frozen=True, slots=True)
class Decision:
    """What the robot must do now, and how it was chosen.

    ``probabilities`` is the distribution ``action`` was drawn from, aligned with
    ``space.actions_of(state)``; ``chain`` lists the silent steps taken before it, in order.
    """

    context: int
    state: int
    action: int
    probabilities: FloatArray
    chain: tuple[ChainStep, ...] = ()

    def chain_transitions(self, episode: int) -> list[Transition]:
        """The silent steps as transitions, to hand to ``Learner.update``."""
        return [
            Transition(
                episode=episode,
                context=self.context,
                state=step.state,
                action=step.action,
                reward=step.reward,
                next_state=step.next_state,
            )
            for step in self.chain
        ]

    def transitions(
        self, episode: int, reward: float, next_state: int, signal: Polarity = Polarity.NEUTRAL
    ) -> list[Transition]:
        """The silent steps and then the visible one, with what followed it (the person's
        reward, the next state and the signal), to hand to ``Learner.update``."""
        visible = Transition(
            episode, self.context, self.state, self.action, reward, next_state, signal
        )
        return [*self.chain_transitions(episode), visible]


@dataclass(frozen=True, slots=True)
class ContextView:
    """What a learner believes in one context, per pair (all arrays have shape (P,)).

    ``kept_visits`` (the filtered count n') and ``measure`` (the temporal measure M) are ``None``
    for learners that have no such notion. ``probabilities`` is each pair's selection probability
    within its own state, as ``select_action`` would draw it now.
    """

    q: FloatArray
    visits: IntArray
    kept_visits: FloatArray | None
    since_last: IntArray
    measure: FloatArray | None
    probabilities: FloatArray
