"""Wire models of the deployment's administration: API keys and fleets."""

from __future__ import annotations

import datetime as dt
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from .common import ClientId

__all__ = ["FleetList", "FleetOut", "KeyCreated", "KeyIn", "KeyList", "KeyOut"]

Role = Literal["robot", "staff", "admin"]


class KeyIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"role": "staff", "fleet": "care-home-north",
                                         "name": "night shift"}]},
    )

    role: Role = Field(description="robot: serves the fleet's users; staff: also looks after "
                       "them (models, history, audit log, reset, export, import, delete) and "
                       "uses the console for its fleet; admin: the whole deployment.")
    fleet: ClientId = Field(default="default", description="The fleet the key belongs to.")
    name: str | None = Field(default=None, max_length=200,
                             description="A label for people, e.g. 'robot7'.")


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
    secret: str = Field(description="The key itself, shown this once: it is stored hashed and "
                        "cannot be shown again.")


class KeyList(BaseModel):
    items: list[KeyOut]


class FleetOut(BaseModel):
    fleet: str
    users: int
    keys: int = Field(description="Keys that are not revoked.")
    episodes: int


class FleetList(BaseModel):
    items: list[FleetOut]
