"""Changes in what a person wants, as Attune decided them (``GET .../changes``)."""

from __future__ import annotations

import datetime as dt
from typing import Literal

from pydantic import BaseModel, Field

from .common import Page
from .profile import Wanted

__all__ = ["ChangeEventOut", "ChangeList", "EvidenceItem", "Moment"]


class Moment(BaseModel):
    episode: int = Field(description="The person's episode index.")
    at: dt.datetime = Field(
        description="When: for `since`, the episode's time as the robot reported it (its local "
        "offset); for `decided`, when the service decided, in UTC."
    )


class EvidenceItem(BaseModel):
    """One episode that showed the change: what the person chose (a service, and the detail
    when known) and what they turned down."""

    episode: int
    chose: Wanted | None
    turned_down: list[Wanted]
    turned_down_offer: bool = Field(description="They turned the robot's offer of help down.")


class ChangeEventOut(BaseModel):
    """What a person wants in one context changed."""

    change_id: str = Field(description="Opaque; changes are listed newest first.")
    user_id: str
    fleet: str
    source: Literal["profile", "routine", "change_test"] = Field(
        description="What decided it: routine, the learner's routine for the context (a "
        "routine it trusted was refused and the person took something else, or turned every "
        "offer down: dts-routine); change_test, the learner's change test (DTS with its test "
        "on); profile, the person's own answers no longer support what they wanted (every "
        "learner without a mechanism of its own)."
    )
    time_slot: str
    situation: str
    since: Moment = Field(description="The first episode of the new wish.")
    decided: Moment = Field(description="The episode whose end decided it, and when.")
    before: Wanted | None = Field(description="What they wanted before.")
    now: Wanted | None = Field(
        description="What they want now; null: they turn it down and chose nothing else yet."
    )
    evidence: list[EvidenceItem] = Field(description="The episodes that showed it, oldest first.")
    summary: str = Field(
        examples=[
            "Since 3 December, Mrs. Lin turns down tea in the afternoon, while stretching "
            "(wanted before)."
        ],
        description="The change in words, for staff.",
    )


class ChangeList(Page):
    items: list[ChangeEventOut]
