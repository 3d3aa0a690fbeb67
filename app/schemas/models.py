from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field

from .common import ActionOut

__all__ = [
    "ActionBelief", "ContextModel", "MissionOut", "ModelOut", "StateModel", "StatsOut",
]


class ActionBelief(BaseModel):
    action: ActionOut
    q: float
    visits: int
    kept_visits: float | None
    since_last: int
    measure: float | None
    p: float


class StateModel(BaseModel):
    state: str
    service: str | None = None
    detail: str | None = None
    actions: list[ActionBelief]


class ContextModel(BaseModel):
    time_slot: str
    situation: str
    states: list[StateModel]


class ModelOut(BaseModel):
    user_id: str
    algorithm: str
    params: dict[str, Any]
    version: int
    episodes: int
    contexts: list[ContextModel]


class StatsOut(BaseModel):
    episodes: int
    missions: int
    interaction_rate: float | None = Field(description="null when there is no episode.")
    success_rate: float | None = Field(description="null when there is no mission.")
    queries_per_mission: float | None = Field(description="null when there is no mission.")
    total_reward: float
    cumulative_reward: list[float]


class TimeSlotOut(BaseModel):
    name: str
    start: str
    end: str


class ServiceOut(BaseModel):
    name: str
    details: list[str]


class MissionOut(BaseModel):
    name: str
    situations: list[str]
    time_slots: list[TimeSlotOut]
    services: list[ServiceOut]
    rewards: dict[str, float]
    unavailable_situations: list[str] = []
    gamma: float
