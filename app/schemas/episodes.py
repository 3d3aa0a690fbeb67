from __future__ import annotations

import datetime as dt
import re
from typing import Literal

from pydantic import AwareDatetime, BaseModel, ConfigDict, Field, field_validator
from pydantic_core import PydanticCustomError

from .common import ActionOut, ClientId, Page, ProbabilityOut

__all__ = [
    "ContextOut",
    "DecisionOut",
    "EpisodeBrief",
    "EpisodeCreated",
    "EpisodeIn",
    "EpisodeList",
    "EpisodeSummary",
    "EpisodeTrace",
    "FeedbackIn",
    "FeedbackOut",
    "FeedbackTrace",
    "OutcomeIn",
    "OutcomeOut",
    "RequestIn",
    "TraceDecision",
]

# The start of an RFC 3339 date-time: a date, "T" (or a space, as RFC 3339 allows), hours and
# minutes; pydantic checks the rest (seconds, fraction, and that there is an offset).
_DATE_TIME = re.compile(r"[0-9]{4}-[0-9]{2}-[0-9]{2}[Tt ][0-9]{2}:[0-9]{2}")


def _number_like(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


Response = Literal["accepted", "rejected", "terminated", "human_request", "none", "answered"]
FeedbackWord = Literal["positive", "negative"]


class RequestIn(BaseModel):
    model_config = ConfigDict(extra="forbid")

    service: str = Field(examples=["ProvideDrink"])
    detail: str | None = Field(default=None, examples=["tea"])


class EpisodeIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "event_id": "robot7-000123",
                    "occurred_at": "2026-11-22T15:10:00+08:00",
                    "situation": "stretching",
                    "initiator": "robot",
                    "request": None,
                    "robot_id": "robot7",
                }
            ]
        },
    )

    event_id: ClientId = Field(description="The robot's id of the event; repeating it replays.")
    occurred_at: AwareDatetime = Field(
        description="RFC 3339 with an offset; the local time of that offset picks the time slot."
    )
    situation: str
    initiator: Literal["robot", "human"] = "robot"
    request: RequestIn | None = Field(
        default=None, description="With initiator human: what the person asked for."
    )
    robot_id: ClientId | None = None

    @field_validator("occurred_at", mode="before")
    @classmethod
    def _rfc3339_text(cls, value: object) -> object:
        # pydantic would take a number, or a text of digits ("1700000000"), as Unix seconds;
        # the contract is an RFC 3339 date-time with an offset, as text
        if isinstance(value, bool | int | float) or (
            isinstance(value, str) and _number_like(value)
        ):
            raise PydanticCustomError(
                "datetime_not_a_number",
                "occurred_at must be an RFC 3339 date-time with an offset, as text "
                "(2026-11-22T15:10:00+08:00), not a number of seconds",
            )
        if isinstance(value, str) and not _DATE_TIME.match(value):
            raise PydanticCustomError(
                "datetime_format",
                "occurred_at must be an RFC 3339 date-time with an offset "
                "(2026-11-22T15:10:00+08:00)",
            )
        return value

    @field_validator("occurred_at")
    @classmethod
    def _in_utc_range(cls, value: dt.datetime) -> dt.datetime:
        # 0001-01-01T00:00+14:00 is a valid RFC 3339 time that has no UTC equivalent here.
        try:
            value.astimezone(dt.UTC)
        except OverflowError:
            raise ValueError("occurred_at is out of the representable range") from None
        return value


class ContextOut(BaseModel):
    time_slot: str
    situation: str


class DecisionOut(BaseModel):
    decision_id: str
    action: ActionOut
    expects: list[str] = Field(description="The responses allowed for this action.")
    probabilities: list[ProbabilityOut] = Field(
        description="The distribution the action was drawn from (sums to 1)."
    )
    chain: list[ProbabilityOut] = Field(
        description="Silent steps the service took first (respond, infer), in order."
    )


class EpisodeCreated(BaseModel):
    episode_id: str
    user_id: str
    status: Literal["open", "closed"]
    context: ContextOut
    state: str
    total_reward: float
    decision: DecisionOut | None
    mission_version: int | None = Field(
        default=None,
        description="The fleet's mission version the episode runs under "
        "(absent in answers stored before missions had versions).",
    )


class OutcomeIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "decision_id": "dec_0123456789abcdef0123456789abcdef",
                    "response": "answered",
                    "service": "ProvideDrink",
                    "detail": None,
                    "feedback": "positive",
                }
            ]
        },
    )

    decision_id: str = Field(max_length=64)
    response: Response
    service: str | None = None
    detail: str | None = None
    feedback: FeedbackWord | None = Field(
        default=None, description="Extra explicit feedback (a smile, a touch)."
    )


EpisodeStatus = Literal["open", "closed", "interrupted"]


class EpisodeBrief(BaseModel):
    episode_id: str
    status: EpisodeStatus = Field(
        description="interrupted: closed by a change of the fleet's "
        "mission before it ended; it takes no more outcomes."
    )
    state: str
    total_reward: float


class OutcomeOut(BaseModel):
    reward: float
    episode: EpisodeBrief
    decision: DecisionOut | None


class FeedbackIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"feedback_id": "robot7-fb-42", "feedback": "positive"}]},
    )

    feedback_id: ClientId
    feedback: FeedbackWord


class FeedbackOut(BaseModel):
    reward: float
    episode: EpisodeBrief


class TraceDecision(BaseModel):
    decision_id: str
    state: str
    action: ActionOut
    probabilities: list[ProbabilityOut]
    chain: list[ProbabilityOut]
    response: str | None
    service: str | None
    detail: str | None
    feedback: str | None
    reward: float | None
    decided_at: dt.datetime
    answered_at: dt.datetime | None


class FeedbackTrace(BaseModel):
    feedback_id: str
    feedback: str
    reward: float
    received_at: dt.datetime


class EpisodeSummary(BaseModel):
    episode_id: str
    user_id: str
    fleet: str = Field(description="The user's fleet.")
    event_id: str
    robot_id: str | None
    status: EpisodeStatus
    context: ContextOut
    initiator: Literal["robot", "human"]
    interaction_class: Literal["I1", "I2", "I3", "none"]
    total_reward: float
    state: str
    occurred_at: dt.datetime
    index: int = Field(description="1-based position of the episode in the user's history.")
    mission_version: int = Field(description="The fleet's mission version it ran under.")


class EpisodeTrace(EpisodeSummary):
    decisions: list[TraceDecision]
    feedback: list[FeedbackTrace]


class EpisodeList(Page):
    items: list[EpisodeSummary]
