from __future__ import annotations

import datetime as dt
from typing import Any

from pydantic import BaseModel, Field

from .common import Page

__all__ = ["AuditActor", "AuditEntryOut", "AuditList"]


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
        "model), user.prior (the user's fleet_prior changed), model.reset, model.export, "
        "model.import, model.rebuild (attune models rebuild --save), key.create, key.revoke, "
        "mission.set, correction.add, correction.lift or fleet.prior.",
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
