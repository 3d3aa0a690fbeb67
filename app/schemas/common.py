from __future__ import annotations

from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, StringConstraints
from pydantic_core import PydanticCustomError

__all__ = [
    "CLIENT_ID_PATTERN",
    "DOT_SEGMENTS",
    "MAX_POSITION",
    "ActionOut",
    "ClientId",
    "ErrorOut",
    "Page",
    "ProbabilityOut",
    "not_a_dot_segment",
    "position_of",
]

CLIENT_ID_PATTERN = r"^[A-Za-z0-9._:-]{1,128}$"
# Episode and audit cursors are positions (a user's episode index, an audit entry's id), which
# the database stores as 32-bit integers: no cursor the API returns is larger.
MAX_POSITION = 2**31 - 1


def position_of(cursor: str) -> int | None:
    """The position a page cursor stands for, or None if the API never returns that cursor."""
    if not (cursor.isascii() and cursor.isdigit()) or len(cursor) > 10:
        return None
    value = int(cursor)
    return value if value <= MAX_POSITION else None


DOT_SEGMENTS = (".", "..")


def not_a_dot_segment(value: str) -> str:
    """Refuse ``.`` and ``..`` as a client-chosen id: the pattern allows their characters, but
    in a URL path they mean the path itself and its parent, so a user (a fleet, a correction)
    of that id could never be opened by its URL."""
    if value in DOT_SEGMENTS:
        raise PydanticCustomError(
            "client_id_dot_segment",
            "'{value}' is not an id: in a URL path '.' and '..' mean this path and the one "
            "above it, so what it names could not be opened",
            {"value": value},
        )
    return value


ClientId = Annotated[
    str, StringConstraints(pattern=CLIENT_ID_PATTERN), AfterValidator(not_a_dot_segment)
]
"""A client-chosen id: ``CLIENT_ID_PATTERN``, and neither ``.`` nor ``..``."""


class ErrorOut(BaseModel):
    """The one error body of the API."""

    error: str = Field(examples=["NotFound"])
    detail: str = Field(examples=["No user 'lin' in your fleet."])
    # exclude_if rather than a wrap serializer: the OpenAPI schema keeps the fields
    fields: list[dict[str, Any]] | None = Field(
        default=None,
        description="Validation errors only: where and what.",
        exclude_if=lambda v: v is None,
    )
    request_id: str | None = Field(
        default=None,
        examples=["3f1c9d2e8b7a4c6d9e0f1a2b3c4d5e6f"],
        description="The request's id, as in its X-Request-ID response header and in the "
        "service's log lines of that request.",
        exclude_if=lambda v: v is None,
    )


class ActionOut(BaseModel):
    """An action of the negotiation: ``kind``, and ``service``/``detail`` where it has them."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {"kind": "initiate"},
                {"kind": "perform", "service": "ProvideDrink", "detail": "tea"},
            ]
        }
    )

    kind: str
    service: str | None = Field(default=None, exclude_if=lambda v: v is None)
    detail: str | None = Field(default=None, exclude_if=lambda v: v is None)


class ProbabilityOut(BaseModel):
    action: ActionOut
    p: float


class Page(BaseModel):
    next_cursor: str | None = Field(
        description="Pass as ?cursor= for the next page; null on the last page."
    )
