"""Rollouts of a candidate learner to a share of a fleet's people
(``/v1/admin/fleets/{fleet}/rollout``)."""

from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from .evaluations import CandidateIn, CandidateOut

__all__ = ["RollbackIn", "RolloutIn", "RolloutOut", "ShadowIn", "ShadowOut"]


class RolloutIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {"candidate": {"algorithm": "hri", "params": {"tau": 0.005}}, "share": 0.2}
            ]
        },
    )

    candidate: CandidateIn
    share: float = Field(
        gt=0,
        le=1,
        description="The share of the fleet's people the candidate serves, above 0 and at most "
        "1. A lower share than the rollout's moves no one; a higher one moves more people.",
    )


class RollbackIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"reason": "the night staff saw more refusals"}]},
    )

    reason: str | None = Field(default=None, max_length=500, description="Why, for the record.")


class ArmOut(BaseModel):
    name: str
    n_people: int = Field(description="People with episodes since they got their arm.")
    n_episodes: int
    mean: float | None = Field(description="Mean return per encounter.")
    std_error: float | None
    effective_people: float


class ComparisonOut(BaseModel):
    """Candidate minus control, per encounter, with an interval valid at every look."""

    candidate: ArmOut
    control: ArmOut
    difference: float | None
    low: float | None
    high: float | None
    std_error: float | None
    df: float | None
    mixture: float | None
    radius: float | None
    verdict: str = Field(description="better, worse, or no difference yet.")
    enough: bool
    reason: str
    alpha: float
    rho: float


class RolloutOut(BaseModel):
    rollout_id: str
    fleet: str
    candidate: CandidateOut
    share: float
    status: Literal["running", "promoted", "rolled_back"]
    started_at: dt.datetime
    started_by: str
    ended_at: dt.datetime | None
    ended_by: str | None = Field(description="A key id, or guard for the automatic roll back.")
    end_reason: str | None
    people: dict[str, int] = Field(description="People per arm (candidate, control).")
    moving: int = Field(
        description="People still to move to the learner their arm gives them (done a person "
        "at a time, in the background, within seconds)."
    )
    comparison: ComparisonOut
    summary: str = Field(description="The comparison in a sentence.")
    guard: bool = Field(description="Whether the guard's condition holds (the candidate worse).")

    @classmethod
    def of(cls, found: dict[str, Any]) -> RolloutOut:
        return cls.model_validate(found)


class ShadowIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"candidate": {"algorithm": "dts"}, "share": 1.0}]},
    )

    candidate: CandidateIn
    share: float = Field(
        default=1.0,
        gt=0,
        le=1,
        description="The share of the fleet's people whose decisions the candidate also makes "
        "(above 0, at most 1; all of them by default).",
    )


class ShadowOut(BaseModel):
    shadow_id: str
    fleet: str
    candidate: CandidateOut
    share: float
    status: Literal["running", "stopped"]
    started_at: dt.datetime
    started_by: str
    stopped_at: dt.datetime | None
    stopped_by: str | None
    checked_until: dt.datetime = Field(
        description="The episodes closed before this time have been looked at."
    )
    decisions: int = Field(description="Decisions the candidate made beside the robots'.")
    agreeing: int = Field(description="Those where it drew the action the robot was told.")
    agreement: float | None = Field(description="agreeing / decisions.")
    expected_agreement: float | None = Field(
        description="The mean of the candidate's probability of the robot's action."
    )
    people: int
    estimate: dict[str, Any] | None = Field(
        description="The newest off-policy estimate of the candidate over the fleet's episodes "
        "since the shadow started: as an evaluation's result, without per-person rows."
    )
    estimated_at: dt.datetime | None
    summary: str = Field(description="What it found, in words: the two sentences below.")
    agreement_summary: str = Field(description="How often it would have done the same.")
    estimate_summary: str | None = Field(description="What its estimate says (null before it).")
