from __future__ import annotations

from typing import Annotated

import orjson
from fastapi import Path, Query, Request, Response
from fastapi.responses import StreamingResponse
from pydantic import AfterValidator, BeforeValidator
from pydantic_core import PydanticCustomError

from app.api.middleware import HEAD_KEY
from app.schemas.common import CLIENT_ID_PATTERN, not_a_dot_segment
from app.services import views
from app.services.context import Principal, ServiceContext
from app.services.episodes import Written
from app.services.subject import Export


def _true_or_false(value: object) -> object:
    """A query boolean as the contract spells it: ``true`` or ``false`` (FastAPI alone would
    also take 1, yes, on, True... and their opposites)."""
    if isinstance(value, bool):  # the default
        return value
    if value == "true":
        return True
    if value == "false":
        return False
    raise PydanticCustomError("bool_parsing", "Input should be true or false")


QueryBool = Annotated[bool, BeforeValidator(_true_or_false)]
"""A boolean query parameter: exactly ``true`` or ``false``, else 422 naming it."""

IdRule = AfterValidator(not_a_dot_segment)  # neither "." nor "..", whatever the pattern allows
UserId = Annotated[
    str,
    Path(
        pattern=CLIENT_ID_PATTERN,
        description="Client-chosen user id (neither '.' nor '..').",
        examples=["lin"],
    ),
    IdRule,
]
EpisodeId = Annotated[
    str,
    Path(
        max_length=128,
        description="Server-chosen episode id.",
        examples=["ep_0123456789abcdef0123456789abcdef"],
    ),
]
# Integer query parameters are bounded, so that no value reaches the database as an integer it
# cannot hold (a 422 naming the parameter and its range instead, on every engine).
LIMIT_MAX = 500
LAST_MAX = 1_000_000
Limit = Annotated[int, Query(ge=1, le=LIMIT_MAX, description=f"Items per page, 1 to {LIMIT_MAX}.")]
Last = Annotated[
    int | None,
    Query(
        ge=1,
        le=LAST_MAX,
        description=f"Only the last N episodes, 1 to {LAST_MAX} (all of them when absent).",
    ),
]
_CURSOR = (
    "The `next_cursor` of the previous page, passed back unchanged; treat it as opaque. A "
    "value that is not of the shape this API returns (the pattern, and for numbers a "
    "position below 2147483648) is refused with 422; a value of that shape names a "
    "position in the list, and the page starts after it."
)
# Episode and audit pages: the position of the last item of the previous page.
SeqCursor = Annotated[str | None, Query(pattern=r"^[0-9]{1,10}$", description=_CURSOR)]
# Users pages: the fleet and user id of the last user of the previous page, base64url-encoded
# without padding.
UserCursor = Annotated[str | None, Query(pattern=r"^[A-Za-z0-9_-]{1,344}$", description=_CURSOR)]
Fleet = Annotated[
    str | None,
    Query(
        pattern=CLIENT_ID_PATTERN,
        examples=["care-home-north"],
        description="The user's fleet, for admin keys (default: the key's own fleet). Robot and "
        "staff keys work in their own fleet: another fleet is answered as a user that does not "
        "exist.",
    ),
    IdRule,
]
MissionFleet = Annotated[
    str | None,
    Query(
        pattern=CLIENT_ID_PATTERN,
        examples=["care-home-north"],
        description="Whose mission, for admin keys (default: the key's own fleet). Other keys may "
        "name only their own fleet (403 otherwise).",
    ),
    IdRule,
]
FleetName = Annotated[
    str,
    Path(pattern=CLIENT_ID_PATTERN, examples=["care-home-north"], description="The fleet."),
    IdRule,
]
REPLAY_HEADER = {
    "Idempotent-Replay": {
        "description": "true when this repeats an earlier identical write.",
        "schema": {"type": "string", "enum": ["true"]},
    },
}


def written(result: Written) -> Response:
    """A robot write's answer (with ``Idempotent-Replay: true`` when it repeats an earlier
    one), encoded once, with orjson."""
    headers = {"Idempotent-Replay": "true"} if result.replay else None
    return Response(
        orjson.dumps(result.body),
        status_code=result.status,
        headers=headers,
        media_type="application/json",
    )


def no_content() -> Response:
    return Response(status_code=204)


def record_read(
    request: Request, principal: Principal, user_id: str, fleet: str | None, what: str
) -> None:
    """A staff or admin read of the person's data, recorded before the answer leaves (who
    looked: ``app.services.views``); a robot's read is not, nor a HEAD (it sends no data)."""
    if request.scope.get(HEAD_KEY):
        return
    views.record(
        request.app.state.db,
        request.app.state.settings,
        principal,
        user_id=user_id,
        fleet=fleet,
        what=what,
    )


def export_response(request: Request, started: Export, ctx: ServiceContext) -> StreamingResponse:
    """A person's export as the download the API and the console answer: streamed from
    transactions of its own, never cached."""
    return StreamingResponse(
        started.stream(request.app.state.db, ctx),
        media_type="application/json",
        headers={
            "Content-Disposition": f'attachment; filename="{started.filename}"',
            "Cache-Control": "no-store",
        },
    )
