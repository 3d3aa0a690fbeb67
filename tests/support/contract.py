"""The contract's one error body, as every test checks it."""

from __future__ import annotations

from typing import Any

NAMES = {
    400: "BadRequest",
    401: "Unauthorized",
    403: "Forbidden",
    404: "NotFound",
    409: "Conflict",
    413: "PayloadTooLarge",
    415: "UnsupportedMediaType",
    422: "ValidationError",
}


def assert_error(r: Any, status: int | tuple[int, ...], name: str | None = None) -> dict[str, Any]:
    """``r`` (an httpx or TestClient response) has one of the statuses and the contract's error
    body: JSON ``{"error", "detail"}`` (plus ``fields`` for validation, and the request id of
    the ``X-Request-ID`` header), the error named for the status, no traceback. The body."""
    statuses = status if isinstance(status, tuple) else (status,)
    assert r.status_code in statuses, r.text
    assert r.headers["content-type"].startswith("application/json")
    body: dict[str, Any] = r.json()
    assert set(body) <= {"error", "detail", "fields", "request_id"}
    assert body["request_id"] == r.headers["x-request-id"]
    assert isinstance(body["error"], str)
    assert body["error"]
    assert isinstance(body["detail"], str)
    assert body["detail"]
    assert "Traceback" not in r.text
    if name is not None:
        assert body["error"] == name
    if r.status_code in NAMES:
        assert body["error"] == NAMES[r.status_code]
    return body
