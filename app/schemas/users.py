from __future__ import annotations

import datetime as dt
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, StrictBool

from .common import Page

__all__ = ["LearnerSpec", "UserIn", "UserList", "UserOut"]


class LearnerSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")

    algorithm: str = Field(
        default="dts-routine",
        description="dts-routine (the default), dts-adapt, hri, rmax, qlearning or dts.",
        examples=["dts-routine"],
    )
    params: dict[str, Any] = Field(
        default_factory=dict,
        examples=[{"tau": 0.01}],
        description="The algorithm's parameters; omitted ones keep their defaults.",
    )


class UserIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "display_name": "Mrs. Lin",
                    "learner": {"algorithm": "hri", "params": {"tau": 0.01}},
                }
            ]
        },
    )

    display_name: str | None = Field(default=None, max_length=200)
    learner: LearnerSpec | None = None
    fleet_prior: StrictBool | None = Field(
        default=None,
        description="Whether the person takes part in the fleet's prior: a new "
        "user starts from it, and the user's model adds to it. false: neither. Omitted: true "
        "for a new user, unchanged for an existing one. A JSON boolean: true or false, not a "
        "string or a number.",
    )


class UserOut(BaseModel):
    user_id: str
    fleet: str
    display_name: str | None
    learner: LearnerSpec
    created_at: dt.datetime
    episodes: int
    fleet_prior: bool = Field(description="Whether the person takes part in the fleet's prior.")


class UserList(Page):
    items: list[UserOut]
