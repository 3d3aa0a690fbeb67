"""Evaluations of candidate learners on a fleet's logs, as background jobs
(``/v1/admin/fleets/{fleet}/evaluations``)."""

from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from .common import ClientId

__all__ = [
    "CandidateIn",
    "EvaluationIn",
    "EvaluationList",
    "EvaluationOut",
]


class CandidateIn(BaseModel):
    """A learner to estimate: an algorithm and the parameters that differ from its defaults (as
    a person's ``learner`` is given)."""

    model_config = ConfigDict(extra="forbid")

    algorithm: str = Field(
        max_length=32,
        examples=["dts"],
        description="hri, dts, dts-adapt, dts-routine, rmax, qlearning, or default (the "
        "learner a person gets when nobody chooses one).",
    )
    params: dict[str, Any] = Field(
        default_factory=dict, examples=[{"tau": 0.005}], description="Only those to change."
    )


class EvaluationCandidateIn(CandidateIn):
    """A learner to estimate, and where each person's candidate starts."""

    algorithm: str = Field(
        max_length=32,
        examples=["dts"],
        description="hri, dts, dts-adapt, dts-routine, rmax, qlearning, default (the learner a "
        "person gets when nobody chooses one), or current (each person's own learner: give "
        "fleet_prior then).",
    )
    fleet_prior: bool | None = Field(
        default=None,
        description="true: each person's candidate starts from the fleet's prior (those who "
        "started fresh get the prior the fleet's other people make today); false: fresh "
        "(those who started from the prior start without it); left out: where the person's "
        "model started.",
    )


class EvaluationIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "request_id": "december-review",
                    "candidates": [
                        {"algorithm": "dts"},
                        {"algorithm": "hri", "params": {"tau": 0.005}},
                    ],
                    "since": "2026-11-01T00:00:00+00:00",
                }
            ]
        },
    )

    request_id: ClientId = Field(
        description="Yours, unique per fleet: the same request sent again gets the same "
        "evaluation (Idempotent-Replay: true); another request under the same id gets 409."
    )
    candidates: list[EvaluationCandidateIn] = Field(
        min_length=1, max_length=5, description="One to five learners to estimate."
    )
    since: dt.datetime | None = Field(
        default=None,
        description="Count the episodes that happened from then on (RFC 3339 with an offset); "
        "the candidates still learn from all that came before.",
    )
    until: dt.datetime | None = Field(
        default=None, description="Count the episodes that happened before then."
    )
    estimator: Literal["wpdis", "pdis", "dr", "wdr"] | None = Field(
        default=None,
        description="wpdis (the default: weighted per-decision importance sampling), pdis, "
        "dr (doubly robust) or wdr (weighted doubly robust); docs/method.md §17.",
    )


class Interval(BaseModel):
    low: float
    high: float
    method: str
    confidence: float


class EstimateOut(BaseModel):
    """One estimate of a learner's return per encounter, with what it rests on."""

    estimator: str
    value: float | None = Field(description="Null when there is not enough evidence.")
    interval: Interval | None
    n_episodes: int
    n_clusters: int = Field(description="People whose episodes count.")
    ess: float | None = Field(description="Effective sample size of the weighted episodes.")
    clip: float | None
    clipped_share: float
    unsupported_mean: float = Field(
        description="Mean share of the candidate's choices that the logs never show."
    )
    unsupported_max: float
    enough: bool
    reason: str = Field(description="Why there is not enough evidence; empty when there is.")
    weight_mean: float | None


class DifferenceOut(BaseModel):
    value: float
    low: float
    high: float
    method: str
    confidence: float


class CandidateResultOut(BaseModel):
    key: str
    label: str
    algorithm: str
    params: dict[str, Any]
    fleet_prior: bool | None = Field(
        default=None, description="Where each person's candidate started (see the request)."
    )
    enough: bool
    reason: str
    estimate: EstimateOut
    difference: DifferenceOut | None = Field(
        description="Candidate minus what the robots earn now, per encounter, with its interval."
    )
    verdict: str = Field(description="What it found, in words.")
    entries_refused: int


class PersonResultOut(BaseModel):
    user_id: str
    algorithm: str = Field(description="The learner that served them (the logging learner).")
    episodes: int
    mean_return: float
    logged: EstimateOut
    candidates: dict[str, EstimateOut] = Field(description="By candidate key.")


class SkippedPerson(BaseModel):
    user_id: str
    reason: str


class EvaluationResult(BaseModel):
    fleet: str
    since: str | None
    until: str | None
    estimator: str
    confidence: float
    people: int
    people_counted: int
    episodes: int
    learners: dict[str, int] = Field(description="The fleet's people per learner now.")
    logged: EstimateOut = Field(description="What the robots earn now, per encounter.")
    candidates: list[CandidateResultOut]
    persons: list[PersonResultOut] | None = Field(
        default=None, description="Per person (absent from lists and with ?persons=false)."
    )
    skipped: dict[str, int] = Field(description="Episodes not counted, by reason.")
    people_skipped: list[SkippedPerson]


class CandidateOut(BaseModel):
    key: str
    label: str
    algorithm: str
    params: dict[str, Any]
    fleet_prior: bool | None = Field(
        default=None, description="Where each person's candidate starts (see the request)."
    )


class Requester(BaseModel):
    key_id: str
    role: str


class Progress(BaseModel):
    people_done: int
    people_total: int | None = Field(description="Known once the job has started.")


class EvaluationOut(BaseModel):
    """An evaluation job: what was asked, how far it got, and its result once done."""

    evaluation_id: str
    fleet: str
    request_id: str
    status: Literal["queued", "running", "done", "failed", "cancelled"]
    candidates: list[CandidateOut]
    since: str | None
    until: str | None
    estimator: str
    requested_by: Requester
    created_at: dt.datetime
    started_at: dt.datetime | None
    finished_at: dt.datetime | None
    progress: Progress
    cancel_requested: bool
    error: str | None = Field(description="Why it failed, in words.")
    result: EvaluationResult | None


class EvaluationList(BaseModel):
    items: list[EvaluationOut]
    next_cursor: str | None
