"""The learners the service ships, by algorithm name."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..config import PARAMS
from ..mission import Mission
from ..protocols import Learner
from ..state import StateFormatError
from .base import TabularLearner
from .dts import DtsAdaptLearner, DtsLearner, DtsRoutineLearner
from .hri import HriLearner
from .qlearning import QLearner
from .rmax import RmaxLearner

__all__ = [
    "ALGORITHMS",
    "DtsAdaptLearner",
    "DtsRoutineLearner",
    "DtsLearner",
    "HriLearner",
    "QLearner",
    "RmaxLearner",
    "TabularLearner",
    "learner_from_state",
    "make_learner",
]

ALGORITHMS: dict[str, type[TabularLearner[Any]]] = {
    cls.algorithm: cls
    for cls in (HriLearner, RmaxLearner, QLearner, DtsLearner, DtsAdaptLearner, DtsRoutineLearner)
}


def make_learner(
    algorithm: str, params: Mapping[str, Any] | None, mission: Mission
) -> TabularLearner[Any]:
    """A fresh learner; ``ValueError`` with a sentence for an unknown algorithm or parameter."""
    cls = ALGORITHMS.get(algorithm) if isinstance(algorithm, str) else None
    if cls is None:
        raise ValueError(
            f"algorithm must be one of {', '.join(sorted(ALGORITHMS))}; got {algorithm!r}."
        )
    return cls(mission, PARAMS[algorithm].from_dict(params))


def learner_from_state(doc: Mapping[str, Any], mission: Mission) -> TabularLearner[Any]:
    """Import an exported state document (``TabularLearner.to_state``)."""
    if not isinstance(doc, Mapping):
        raise StateFormatError("a learner state must be a JSON object.")
    algorithm = doc.get("algorithm")
    cls = ALGORITHMS.get(algorithm) if isinstance(algorithm, str) else None
    if cls is None:
        raise StateFormatError(
            f"algorithm must be one of {', '.join(sorted(ALGORITHMS))}; got "
            f"{doc.get('algorithm')!r}."
        )
    return cls.from_state(doc, mission)


def _conforms(learner: TabularLearner[Any]) -> Learner:
    return learner  # static check: the base class satisfies the protocol
