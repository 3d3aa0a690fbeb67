"""Wire models of the deployment's administration: API keys and fleets."""

from __future__ import annotations

import datetime as dt
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictInt

from .common import ClientId

__all__ = [
    "FleetList",
    "FleetOut",
    "FleetPriorIn",
    "FleetPriorOut",
    "KeyCreated",
    "KeyIn",
    "KeyList",
    "KeyOut",
]

Role = Literal["robot", "staff", "admin"]


class KeyIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [{"role": "staff", "fleet": "care-home-north", "name": "night shift"}]
        },
    )

    role: Role = Field(
        description="robot: serves the fleet's users; staff: also looks after "
        "them (models, history, audit log, reset, export, import, delete) and "
        "uses the console for its fleet; admin: the whole deployment."
    )
    fleet: ClientId = Field(default="default", description="The fleet the key belongs to.")
    name: str | None = Field(
        default=None, max_length=200, description="A label for people, e.g. 'robot7'."
    )


class KeyOut(BaseModel):
    """A key as listed: never its secret."""

    key_id: str
    role: str
    fleet: str
    name: str | None
    prefix: str = Field(description="The first characters of the secret, to recognise it.")
    created_at: dt.datetime
    revoked_at: dt.datetime | None


class KeyCreated(KeyOut):
    secret: str = Field(
        description="The key itself, shown this once: it is stored hashed and "
        "cannot be shown again."
    )


class KeyList(BaseModel):
    items: list[KeyOut]


class FleetOut(BaseModel):
    fleet: str
    users: int
    keys: int = Field(description="Keys that are not revoked.")
    episodes: int


class FleetList(BaseModel):
    items: list[FleetOut]


class FleetPriorIn(BaseModel):
    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{"enabled": False}]})

    enabled: StrictBool = Field(
        description="Whether the fleet's newcomers start from its prior (a JSON boolean)."
    )


class FleetPriorOut(BaseModel):
    """A fleet's prior for newcomers: whether it is on, and for which learners it is in force."""

    fleet: str
    enabled: bool = Field(description="The fleet's switch (on unless its staff turned it off).")
    in_force: list[str] = Field(
        description="The learners (algorithms) whose newcomers start "
        "from the prior now: enabled, with enough contributors."
    )
    contributors: dict[str, int] = Field(
        description="Per algorithm, the people who can contribute now (at most max_contributors)."
    )
    min_contributors: int
    min_episodes: int
    max_contributors: int
    strength: float = Field(
        description="The weight of the prior, in a newcomer's own answers per negotiation step."
    )
    mission_version: int = Field(description="The contributors' models are laid out for it.")
    shared: str = Field(description="What the prior takes from the contributors' models.")
    updated_at: dt.datetime | None
    updated_by: str | None = Field(description="The key that last turned it on or off.")


class FleetHistoryIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid", json_schema_extra={"examples": [{"history_days": 90}]}
    )

    history_days: StrictInt | None = Field(
        ge=1,
        le=36_500,
        description="How many days of the fleet's raw history (episodes, decisions, answers, "
        "feedback, the model's journal) to keep; null: keep everything.",
    )


class FleetHistoryOut(BaseModel):
    """A fleet's retention window for raw history."""

    fleet: str
    history_days: int | None = Field(description="The window in days; null: kept until erased.")
