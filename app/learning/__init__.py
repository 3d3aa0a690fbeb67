"""Attune's learning core: the negotiation MDP, the learners, simulated users and experiments.

Pure by design: the standard library and numpy only (an import-linter contract enforces it).
"""

from .config import (
    DtsAdaptParams,
    DtsParams,
    DtsRoutineParams,
    HriParams,
    Params,
    QLearningParams,
    RmaxParams,
)
from .learners import ALGORITHMS, learner_from_state, make_learner
from .mission import Mission, MissionError, Rewards, Service, TimeSlot, load_mission, office_mission
from .protocols import Learner
from .remap import (
    MissionDiff,
    NamesDiff,
    Renames,
    RenamesError,
    SpaceMap,
    check_renames,
    diff_missions,
    remap_learner,
)
from .space import Action, ActionKind, NegotiationSpace, StateKind, space_for
from .state import StateFormatError
from .types import (
    ChainStep,
    ContextView,
    Decision,
    Interaction,
    Observation,
    Polarity,
    Transition,
)

__all__ = [
    "ALGORITHMS",
    "Action",
    "ActionKind",
    "ChainStep",
    "ContextView",
    "Decision",
    "DtsAdaptParams",
    "DtsParams",
    "DtsRoutineParams",
    "HriParams",
    "Interaction",
    "Learner",
    "Mission",
    "MissionDiff",
    "MissionError",
    "NamesDiff",
    "NegotiationSpace",
    "Observation",
    "Params",
    "Polarity",
    "QLearningParams",
    "Renames",
    "RenamesError",
    "Rewards",
    "RmaxParams",
    "Service",
    "SpaceMap",
    "StateFormatError",
    "StateKind",
    "TimeSlot",
    "Transition",
    "check_renames",
    "diff_missions",
    "learner_from_state",
    "load_mission",
    "make_learner",
    "office_mission",
    "remap_learner",
    "space_for",
]
