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
        description="user.delete, model.reset, "
        "model.export, model.import, model.rebuild (attune models rebuild "
        "--save), key.create or key.revoke.",
    )
    target: str = Field(description="The user id (user.*, model.*) or key id (key.*).")
    fleet: str | None = Field(description="The target's fleet.")
    detail: dict[str, Any] | None = Field(
        description="Facts of the action (the model version "
        "it produced, the episodes a deletion removed, ...)."
    )


class AuditList(Page):
    items: list[AuditEntryOut]
