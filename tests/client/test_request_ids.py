"""The client's errors carry the service's request id: the one in the X-Request-ID header, the
error body and the service's log line of that request (what a robot's report should quote)."""

from __future__ import annotations

import json
import re
import time
from collections.abc import Iterator
from pathlib import Path

import anyio
import attune_client as a
import pytest

from tests.support.live import LiveService, fresh_database

pytestmark = pytest.mark.live


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveService]:
    """A real ``attune serve`` writing JSON log lines, access lines included."""
    log = tmp_path_factory.mktemp("serve") / "serve.log"
    env = {"ATTUNE_LOG_FORMAT": "json", "ATTUNE_LOG_LEVEL": "info"}
    with fresh_database("sqlite") as url, LiveService(url, log_path=log, env=env) as service:
        yield service


def _access_line(service: LiveService, request_id: str) -> dict[str, object]:
    """The service's one access line of the request. The worker writes it once the response
    has gone, so the client may see the response first: wait for the line (at most 10 s)."""
    deadline = time.monotonic() + 10
    while True:
        whole = Path(service.log_path).read_text().split("\n")[:-1]  # not a line in writing
        lines: list[dict[str, object]] = [
            json.loads(line) for line in whole if line.startswith("{")
        ]
        found = [
            line
            for line in lines
            if line["logger"] == "attune.access" and line.get("request_id") == request_id
        ]
        if found or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    assert len(found) == 1, found
    return found[0]


def test_an_error_carries_the_services_request_id(live: LiveService) -> None:
    key = live.create_key("robot")
    with a.Client(live.url, key, max_retries=0) as client, pytest.raises(a.NotFoundError) as caught:
        client.get_user("nobody")
    error = caught.value
    assert error.request_id is not None
    assert re.fullmatch(r"[0-9a-f]{32}", error.request_id)
    assert isinstance(error.body, dict)
    assert error.body["request_id"] == error.request_id
    line = _access_line(live, error.request_id)
    assert (line["route"], line["status"]) == ("/v1/users/{user_id}", 404)


def test_a_robots_own_request_id_comes_back(live: LiveService) -> None:
    key = live.create_key("robot")

    async def call() -> a.APIStatusError:
        async with a.AsyncClient(
            live.url, key, max_retries=0, headers={"X-Request-ID": "robot7-boot3"}
        ) as client:
            with pytest.raises(a.UnprocessableEntityError) as caught:
                await client.get_stats("lin", last=0)
        return caught.value

    error = anyio.run(call)
    assert error.request_id == "robot7-boot3"
    assert error.detail == "last must be an integer from 1 to 1000000."
    assert _access_line(live, "robot7-boot3")["status"] == 422
