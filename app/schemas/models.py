from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from .common import ActionOut, ClientId

__all__ = [
    "ActionBelief",
    "ContextModel",
    "MissionOut",
    "ModelOut",
    "StartedFrom",
    "StateModel",
    "StatsOut",
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


class StartedFrom(BaseModel):
    kind: Literal["fresh", "imported", "fleet_prior"] = Field(
        description="What the model started from (since its last reset or import): a new "
        "learner, an imported document, or the fleet's prior."
    )
    contributors: int | None = Field(
        default=None,
        description="fleet_prior: how many of the fleet's people the prior "
        "averaged; otherwise null.",
    )


class ModelOut(BaseModel):
    user_id: str
    algorithm: str
    params: dict[str, Any]
    version: int
    episodes: int
    mission_version: int = Field(
        description="The fleet's mission version the model is laid out for."
    )
    started_from: StartedFrom
    contexts: list[ContextModel]


class StatsOut(BaseModel):
    episodes: int
    history_from: dt.datetime | None = Field(
        default=None,
        description="From when the person's raw history is kept (the fleet's retention window "
        "removed what came before; the model and the profile still hold what it taught): "
        "null when all of it is kept. The figures here are over the kept episodes.",
    )
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
    labels: dict[str, str] = Field(
        default={},
        description="Display only (outside the fingerprint): the words staff read for a time "
        "slot, situation, service or detail, by its name, as "
        '{"phone_call": "a phone call"}; a name without one reads as a readable form of '
        'it ("ProvideDrink": "Provide drink").',
    )
    time_zone: str = Field(
        default="UTC",
        description="Display only (outside the fingerprint): the fleet's IANA time zone, in "
        "which the console shows every time.",
    )


class FleetMissionOut(MissionOut):
    fleet: str = Field(description="Whose mission this is.")
    version: int = Field(description="1, 2, 3...: up by one with every change.")
    fingerprint: str = Field(
        description="Names the mission's contents; learner states "
        "exported under this version carry it."
    )


class MissionVersion(BaseModel):
    version: int
    name: str
    fingerprint: str
    created_at: dt.datetime | None = Field(
        description="null: not stored yet (the fleet has "
        "no users and uses the deployment's default)."
    )
    change_id: str | None
    renames: dict[str, Any] | None = Field(
        description="What the change carried across a rename, from the previous version."
    )
    set_by: str | None = Field(
        description="The key that set it (null: the default, stored with the fleet's first user)."
    )
    stored: bool
    mission: MissionOut


class MissionVersionList(BaseModel):
    fleet: str
    current_version: int
    items: list[MissionVersion] = Field(description="Newest first.")


class Renames(BaseModel):
    model_config = ConfigDict(extra="forbid")

    time_slots: dict[str, str] = {}
    situations: dict[str, str] = {}
    services: dict[str, str] = {}
    details: dict[str, str] = Field(
        default={},
        description='Old name to new; "cha": "tea" '
        "renames the detail under every service that has it, "
        '"ProvideDrink/cha": "tea" under one.',
    )


class MissionChangeIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "change_id": "care-menu-2026-12",
                    "renames": {"details": {"cha": "tea"}},
                    "mission": {
                        "name": "care-home",
                        "situations": ["waking", "resting", "visiting"],
                        "unavailable_situations": ["resting"],
                        "time_slots": [
                            {"name": "day", "start": "07:00", "end": "21:00"},
                            {"name": "night", "start": "21:00", "end": "07:00"},
                        ],
                        "services": [{"name": "ProvideDrink", "details": ["tea", "cocoa"]}],
                        "rewards": {
                            "positive": 1.0,
                            "accepted_service": 5.0,
                            "negative": -2.0,
                            "query": -0.5,
                        },
                        "gamma": 0.9,
                    },
                }
            ]
        },
    )

    change_id: ClientId = Field(
        description="Makes the change idempotent: the same change_id "
        "with the same body answers as the first time."
    )
    mission: dict[str, Any] = Field(
        description="The mission document (as GET /v1/mission "
        "answers it, without fleet, version and fingerprint)."
    )
    renames: Renames | None = None


class MissionChanged(BaseModel):
    fleet: str
    version: int = Field(description="The version in force now.")
    previous_version: int | None = Field(description="null: the fleet had none stored.")
    fingerprint: str
    changed: bool = Field(description="false: the mission was already this one (no new version).")
    users_moved: int = Field(description="Models carried to the new version.")
    episodes_interrupted: int = Field(description="Open episodes closed as interrupted.")
    diff: dict[str, Any] | None = Field(
        description="What the change kept, added, removed "
        "and renamed (null for a fleet's first version)."
    )
