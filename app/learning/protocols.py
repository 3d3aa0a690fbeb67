"""The learner protocol: choose an action, learn from what happened. The loop lives outside."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar, Protocol

import numpy as np

from .space import NegotiationSpace
from .types import ContextView, Decision, Observation, Transition

__all__ = ["Learner"]


class Learner(Protocol):
    """What every learner offers; ``app.learning.checks.check_learner`` verifies the contract.

    - ``select_action`` is pure: it reads the learner and draws from ``rng`` only. It follows
      silent steps (respond, infer) itself and returns them as ``Decision.chain``; the caller
      reports them back through ``update`` with the outcome they led to.
    - ``update`` takes the transitions one report resolved (silent steps and the answered action,
      in order). One call is one change of the model: ``version`` goes up by exactly one (an
      empty list changes nothing). Every transition is checked first; a ``ValueError`` leaves
      the learner unchanged.
    - ``feedback`` adds an explicit feedback reward (a smile, a complaint) to the sample of an
      executed pair in a seen episode, open or closed; ``version`` goes up by exactly one, and a
      ``ValueError`` (checked first) leaves the learner unchanged.
    - ``to_state`` exports a self-describing document (plain JSON types, no pickle) that
      ``app.learning.learner_from_state`` turns back into an identical learner.
    """

    algorithm: ClassVar[str]
    space: NegotiationSpace
    version: int

    @property
    def params(self) -> Any: ...

    def select_action(self, obs: Observation, rng: np.random.Generator) -> Decision: ...

    def update(self, transitions: Sequence[Transition]) -> None: ...

    def feedback(self, episode: int, context: int, action: int, reward: float) -> None:
        """Add ``reward`` to the reward of the sample of ``action`` in ``context`` and ``episode``.

        While the episode is open, the pending sample itself carries it (learners that learn at
        close see it); once closed, the learner adds it to its tables. Refused with a
        ``ValueError``: a pair never executed, an episode not seen yet, a reward that is not a
        finite real number. The version goes up by one.
        """
        ...

    def to_state(self) -> dict[str, Any]: ...

    def explain(self, context: int, episode: int) -> ContextView: ...
