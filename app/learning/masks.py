"""Which of the robot's actions are allowed: the one place a learner's choices are restricted.

A learner proposes a distribution over a state's actions (its own policy); before the robot
draws from it, or anyone reads it (``explain``, the profile, the off-line experiments), two kinds
of rule restrict it, in this order:

1. **Staff corrections** of the person (``app.learning.guidance``): ``prefers`` steers, ``avoid``
   and ``quiet`` forbid.
2. **The mission's care rules**: in a context whose situation is one of the mission's
   ``unavailable_situations`` ("do not disturb"), the robot never initiates. At ``OBSERVE`` the
   only choice left is ``pass``, with probability exactly 1, whatever the learner learned, a
   prior or an import brought, or a correction prefers. A person who speaks first is served as
   usual: what follows ``pass`` is the person's choice, and every later state is left as the
   learner and the corrections have it.

Both rules act on the distribution only; the learner's tables learn from what happens exactly as
without them. The rule of the mission needs no model edit: it follows from the mission the model
is laid out for, so a mission change that adds a situation to the list applies to every model
the change moves, and one that removes it lets the learner's own choice decide again. Logged
probabilities stay exact: a forbidden action has probability 0.

Pure: stdlib and numpy.
"""

from __future__ import annotations

import numpy as np

from .guidance import Guidance
from .space import NegotiationSpace
from .types import FloatArray

__all__ = ["initiates_never", "restrict"]

_PASS_ONLY = np.asarray([0.0, 1.0], dtype=np.float64)
_PASS_ONLY.setflags(write=False)


def initiates_never(space: NegotiationSpace, guidance: Guidance, context: int) -> bool:
    """Whether the robot is forbidden to initiate in ``context``: the mission's care rule (an
    unavailable situation) or a staff ``quiet`` correction in force there."""
    return bool(space.unavailable[context]) or guidance.forbids_initiating(space, context)


def restrict(
    space: NegotiationSpace,
    guidance: Guidance,
    context: int,
    state: int,
    probabilities: FloatArray,
) -> FloatArray:
    """The distribution over ``state``'s actions (``probabilities``, the learner's own, in the
    order of ``space.actions_of(state)``) once the corrections and the mission's care rules
    apply. The input is not changed."""
    out = probabilities
    if guidance:
        out = guidance.adjust(space, context, state, out)
    if state == space.OBSERVE and space.unavailable[context]:
        # (initiate, pass): root_actions are the first two pairs, in that order.
        return _PASS_ONLY
    return out
