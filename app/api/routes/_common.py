from __future__ import annotations

from typing import Annotated

import orjson
from fastapi import Path, Response

from app.schemas.common import CLIENT_ID_PATTERN
from app.services.episodes import Written

UserId = Annotated[str, Path(pattern=CLIENT_ID_PATTERN, description="Client-chosen user id.",
                             examples=["lin"])]
EpisodeId = Annotated[str, Path(max_length=128, description="Server-chosen episode id.",
                                examples=["ep_0123456789abcdef0123456789abcdef"])]
REPLAY_HEADER = {
    "Idempotent-Replay": {"description": "true when this repeats an earlier identical write.",
                          "schema": {"type": "string", "enum": ["true"]}},
}


def written(result: Written) -> Response:
    """A robot write's answer (with ``Idempotent-Replay: true`` when it repeats an earlier
    one), encoded once, with orjson."""
    headers = {"Idempotent-Replay": "true"} if result.replay else None
    return Response(orjson.dumps(result.body), status_code=result.status, headers=headers,
                    media_type="application/json")


def no_content() -> Response:
    return Response(status_code=204)
