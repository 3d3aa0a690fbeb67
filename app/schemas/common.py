from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, StringConstraints, model_serializer
from pydantic_core.core_schema import SerializerFunctionWrapHandler

__all__ = ["CLIENT_ID_PATTERN", "ActionOut", "ClientId", "ErrorOut", "Page", "ProbabilityOut"]

CLIENT_ID_PATTERN = r"^[A-Za-z0-9._:-]{1,128}$"
ClientId = Annotated[str, StringConstraints(pattern=CLIENT_ID_PATTERN)]


class ErrorOut(BaseModel):
    """The one error body of the API."""

    error: str = Field(examples=["NotFound"])
    detail: str = Field(examples=["No user 'lin' in your fleet."])
    fields: list[dict[str, Any]] | None = Field(
        default=None, description="Validation errors only: where and what.",
    )

    @model_serializer(mode="wrap")
    def _drop_empty_fields(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        out: dict[str, Any] = handler(self)
        if out.get("fields") is None:
            out.pop("fields", None)
        return out


class ActionOut(BaseModel):
    """An action of the negotiation: ``kind``, and ``service``/``detail`` where it has them."""

    model_config = ConfigDict(json_schema_extra={"examples": [{"kind": "initiate"},
                                                              {"kind": "perform",
                                                               "service": "ProvideDrink",
                                                               "detail": "tea"}]})

    kind: str
    service: str | None = None
    detail: str | None = None

    @model_serializer(mode="wrap")
    def _omit_absent(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        out: dict[str, Any] = handler(self)
        return {k: v for k, v in out.items() if v is not None}


class ProbabilityOut(BaseModel):
    action: ActionOut
    p: float


class Page(BaseModel):
    next_cursor: str | None = Field(
        description="Pass as ?cursor= for the next page; null on the last page."
    )
