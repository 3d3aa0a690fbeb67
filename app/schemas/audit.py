from __future__ import annotations

import datetime as dt
from typing import Any

from pydantic import BaseModel, Field

from .common import Page

__all__ = ["AuditActor", "AuditEntryOut", "AuditList", "ViewActor", "ViewList", "ViewOut"]


class AuditActor(BaseModel):
    """The key that acted (``key_id`` "cli": an operator on the command line)."""

    key_id: str
    role: str
    fleet: str


class AuditEntryOut(BaseModel):
    """One admin action: who, what, when."""

    id: str = Field(description="Opaque; entries are listed newest first.")
    at: dt.datetime
    actor: AuditActor
    action: str = Field(
        examples=["user.delete"],
        description="user.delete, user.learner (a change of learner, which replaces the "
        "model), user.prior (the user's fleet_prior changed), user.export, model.reset, "
        "model.export, model.import, model.rebuild (attune models rebuild --save), key.create, "
        "key.revoke, mission.set, correction.add, correction.lift or fleet.prior.",
    )
    target: str = Field(
        description="The user id (user.*, model.*, correction.*), key id (key.*) or fleet "
        "(mission.set, fleet.prior)."
    )
    fleet: str | None = Field(description="The target's fleet.")
    detail: dict[str, Any] | None = Field(
        description="Facts of the action (the model version it produced, what a correction "
        'said, ...); {"erased": true} for the entries about a person who was erased, and for '
        "the erasure's own (user.delete)."
    )


class AuditList(Page):
    items: list[AuditEntryOut]


class ViewActor(AuditActor):
    """The key that read (its ``name`` if it has one, as staff named it: "night-shift")."""

    name: str | None


class ViewOut(BaseModel):
    """One read of a person's data by staff or an admin."""

    id: str = Field(description="Opaque; entries are listed newest first.")
    at: dt.datetime
    user_id: str
    fleet: str
    actor: ViewActor
    what: str = Field(
        examples=["profile"],
        description="What was read: user, model, stats, profile, corrections, episodes, "
        "episode, export, subject (the API; subject: the person's export), or a console page: "
        "console.profile, console.details, console.why, console.episodes, console.trace.",
    )
    via: str = Field(description="api or console.")


class ViewList(Page):
    items: list[ViewOut]
