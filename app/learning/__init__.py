"""Attune's learning core: the negotiation MDP, the learners, simulated users and experiments.

Pure by design: the standard library and numpy only (an import-linter contract enforces it).
"""

from .config import DtsParams, HriParams, Params, QLearningParams, RmaxParams
from .learners import ALGORITHMS, learner_from_state, make_learner
from .mission import Mission, MissionError, Rewards, Service, TimeSlot, load_mission, office_mission
from .protocols import Learner
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
    "DtsParams",
    "HriParams",
    "Interaction",
    "Learner",
    "Mission",
    "MissionError",
    "NegotiationSpace",
    "Observation",
    "Params",
    "Polarity",
    "QLearningParams",
    "Rewards",
    "RmaxParams",
    "Service",
    "StateFormatError",
    "StateKind",
    "TimeSlot",
    "Transition",
    "learner_from_state",
    "load_mission",
    "make_learner",
    "office_mission",
    "space_for",
]
