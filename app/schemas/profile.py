"""What Attune believes about a person, in plain words, and the staff's corrections."""

from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from .common import ClientId
from .models import StartedFrom

__all__ = [
    "Certainty",
    "ChangeOut",
    "CorrectionIn",
    "CorrectionList",
    "CorrectionOut",
    "EvidenceOut",
    "ProfileContext",
    "ProfileOut",
    "RobotWill",
    "Wanted",
]

Certainty = Literal["unknown", "tentative", "confident"]
CorrectionKind = Literal["prefers", "avoid", "quiet"]


class Wanted(BaseModel):
    service: str
    detail: str | None = None


class EvidenceOut(BaseModel):
    """What the person did in this context (all their episodes there)."""

    accepted: int = Field(description="Services the robot performed and the person took.")
    refused: int = Field(description="Offers and services the person turned down.")
    asked_for: int = Field(description="Times the person asked for a service themselves.")
    answered: int = Field(description="Questions of the robot the person answered.")
    last_seen: dt.datetime | None = Field(
        description="The latest episode here, in the person's local time (the offset the "
        "robot sent with it)."
    )
    support: int = Field(
        description="Of the person's last answers here (up to 8), how many "
        "agree with what they are believed to want."
    )
    recent: int = Field(description="How many answers that is out of.")


class RobotWill(BaseModel):
    """What the robot will most likely do when it meets the person here."""

    action: Literal["offer", "wait_to_be_asked", "stay_away"]
    service: str | None = Field(
        description="What it would bring if it offers (None: it would "
        "ask first, or it does not offer)."
    )
    detail: str | None
    asks_first: bool = Field(
        description="It would most likely ask what the person wants before bringing anything."
    )
    probability: float = Field(description="Chance that it offers on its own.")


class ChangeOut(BaseModel):
    """The person's recent answers contradict what they wanted before."""

    at: dt.datetime | None = Field(description="When the new wish first showed, local time.")
    episode: int = Field(description="The user's episode index where it first showed.")
    before: Wanted | None
    now: Wanted | None
    by: Literal["person"] = "person"
    overrides: str | None = Field(
        default=None, description="The staff correction the person's answers overrode, if any."
    )


class ProfileContext(BaseModel):
    time_slot: str
    situation: str
    episodes: int = Field(description="Episodes here, open ones included.")
    open_episodes: int
    wants: Wanted | None
    certainty: Certainty
    source: Literal["person", "staff"] | None = Field(
        description="Where the belief comes from: the person's answers, or a staff correction."
    )
    evidence: EvidenceOut
    robot_will: RobotWill
    summary: str
    changed: ChangeOut | None
    corrections: list[str] = Field(description="Ids of the corrections that apply here.")


class CorrectionIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "correction_id": "c-2026-11-30-001",
                    "time_slot": "morning",
                    "situation": "arriving",
                    "kind": "prefers",
                    "service": "ProvideDrink",
                    "detail": "coffee",
                    "note": "Her daughter says she always has coffee first.",
                }
            ]
        },
    )

    correction_id: ClientId = Field(description="Your id of the correction; repeating it replays.")
    time_slot: str = Field(max_length=64)
    situation: str = Field(max_length=64)
    kind: CorrectionKind
    service: str | None = Field(default=None, max_length=64)
    detail: str | None = Field(default=None, max_length=64)
    note: str | None = Field(default=None, max_length=500)


class CorrectionOut(BaseModel):
    correction_id: str
    kind: CorrectionKind
    time_slot: str
    situation: str
    service: str | None
    detail: str | None
    note: str | None
    author: str = Field(description="The key id that made it.")
    created_at: dt.datetime
    status: Literal["in_force", "overridden", "lifted", "idle"] = Field(
        description="in_force; overridden (the person's own answers contradicted a prefers); "
        "lifted (by staff); idle (the fleet's mission no longer has its names)."
    )
    overridden_at: dt.datetime | None = None
    lifted_at: dt.datetime | None = None
    lifted_by: str | None = None
    model_version: int = Field(description="The model version the correction produced.")


class CorrectionList(BaseModel):
    items: list[CorrectionOut]


class RolloutArmOut(BaseModel):
    """A person's arm in a fleet's rollout of a candidate learner."""

    rollout_id: str
    arm: Literal["candidate", "control"] = Field(
        description="candidate: served by the rollout's candidate; control: by the learner "
        "they had."
    )
    assigned_at: dt.datetime
    candidate: dict[str, Any] = Field(description="The rollout's candidate: key, label, ...")
    rollout_status: Literal["running", "promoted", "rolled_back"]
    moving: bool = Field(
        default=False, description="Their move to the learner their arm gives them is under way."
    )


class ProfileOut(BaseModel):
    user_id: str
    display_name: str | None
    episodes: int = Field(description="All the person's episodes, open ones included.")
    open_episodes: int
    utc_offset: int | None = Field(
        description="Minutes east of UTC of the person's latest "
        "event: the local time the profile speaks in."
    )
    started_from: StartedFrom = Field(
        description="What the model started from: as in GET .../model."
    )
    contexts: list[ProfileContext]
    corrections: list[CorrectionOut] = Field(
        description="The corrections in force or overridden (lifted ones: GET .../corrections)."
    )
    rollout: RolloutArmOut | None = Field(
        default=None,
        description="The person's arm in the newest rollout of a learner that gave them one "
        "(null: none did).",
    )
