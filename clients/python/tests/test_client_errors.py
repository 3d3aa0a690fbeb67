"""Every error status becomes its own exception class, carrying the contract's error body."""

from __future__ import annotations

import attune_client as a
import httpx
import pytest
from attune_client_fakes import MakeClient

STATUS_CLASSES = [
    (400, a.BadRequestError, "BadRequest"),
    (401, a.AuthenticationError, "Unauthorized"),
    (403, a.PermissionDeniedError, "Forbidden"),
    (404, a.NotFoundError, "NotFound"),
    (409, a.ConflictError, "Conflict"),
    (413, a.PayloadTooLargeError, "PayloadTooLarge"),
    (422, a.UnprocessableEntityError, "ValidationFailed"),
    (429, a.RateLimitError, "TooManyRequests"),
    (500, a.InternalServerError, "InternalError"),
    (501, a.InternalServerError, "NotImplemented"),
    (503, a.ServiceUnavailableError, "ServiceUnavailable"),
    (418, a.APIStatusError, "Teapot"),
]


@pytest.mark.parametrize(("status", "cls", "name"), STATUS_CLASSES)
def test_each_status_has_its_class(
    make_client: MakeClient, status: int, cls: type[a.APIStatusError], name: str
) -> None:
    def handler(request: httpx.Request) -> httpx.Response:
        return httpx.Response(
            status,
            json={"error": name, "detail": f"Because {status}."},
            headers={"X-Request-ID": "req-42"},
        )

    client = make_client(handler, max_retries=0)
    with pytest.raises(cls) as caught:
        client.get_user("lin")
    err = caught.value
    assert type(err) is cls
    assert err.status_code == status
    assert err.error == name
    assert err.detail == f"Because {status}."
    assert err.request_id == "req-42"
    assert err.response.status_code == status
    assert err.body == {"error": name, "detail": f"Because {status}."}
    assert str(err) == f"{status} {name}: Because {status}."


def test_validation_fields_are_kept(make_client: MakeClient) -> None:
    fields = [{"loc": ["body", "situation"], "msg": "bad", "type": "value_error"}]

    def handler(request: httpx.Request) -> httpx.Response:
        return httpx.Response(
            422, json={"error": "ValidationFailed", "detail": "situation: bad.", "fields": fields}
        )

    with pytest.raises(a.UnprocessableEntityError) as caught:
        make_client(handler).get_user("lin")
    assert caught.value.fields == fields


def test_no_request_id_without_the_header(make_client: MakeClient) -> None:
    def handler(request: httpx.Request) -> httpx.Response:
        return httpx.Response(404, json={"error": "NotFound", "detail": "No user."})

    with pytest.raises(a.NotFoundError) as caught:
        make_client(handler).get_user("lin")
    assert caught.value.request_id is None
    assert caught.value.fields is None


@pytest.mark.parametrize(
    ("status", "cls"),
    [(502, a.InternalServerError), (404, a.NotFoundError), (413, a.PayloadTooLargeError)],
)
def test_a_body_that_is_not_json_still_gives_the_class(
    make_client: MakeClient, status: int, cls: type[a.APIStatusError]
) -> None:
    def handler(request: httpx.Request) -> httpx.Response:
        return httpx.Response(
            status,
            text="<html><body><h1>Bad   gateway</h1></body></html>",
            headers={"Content-Type": "text/html"},
        )

    with pytest.raises(cls) as caught:
        make_client(handler, max_retries=0).get_user("lin")
    err = caught.value
    assert err.status_code == status
    assert err.detail == "<html><body><h1>Bad gateway</h1></body></html>"
    assert err.error  # the reason phrase, e.g. "BadGateway"
    assert " " not in err.error


def test_an_empty_body_gives_the_reason_phrase(make_client: MakeClient) -> None:
    def handler(request: httpx.Request) -> httpx.Response:
        return httpx.Response(409)

    with pytest.raises(a.ConflictError) as caught:
        make_client(handler).get_user("lin")
    assert caught.value.error == "Conflict"
    assert caught.value.detail == "Conflict"


def test_json_that_is_not_the_error_shape(make_client: MakeClient) -> None:
    def handler(request: httpx.Request) -> httpx.Response:
        return httpx.Response(400, json=["unexpected"])

    with pytest.raises(a.BadRequestError) as caught:
        make_client(handler).get_user("lin")
    assert caught.value.error == "BadRequest"
    assert caught.value.detail == "Bad Request"
    assert caught.value.body == ["unexpected"]


def test_rate_limit_and_unavailable_carry_retry_after(make_client: MakeClient) -> None:
    def handler(request: httpx.Request) -> httpx.Response:
        status = 429 if request.url.path.endswith("a") else 503
        return httpx.Response(
            status, headers={"Retry-After": "7"}, json={"error": "Busy", "detail": "Later."}
        )

    client = make_client(handler, max_retries=0)
    with pytest.raises(a.RateLimitError) as limited:
        client.get_user("a")
    assert limited.value.retry_after == 7.0
    with pytest.raises(a.ServiceUnavailableError) as unavailable:
        client.get_user("b")
    assert unavailable.value.retry_after == 7.0


def test_connection_errors_keep_the_request(make_client: MakeClient) -> None:
    def handler(request: httpx.Request) -> httpx.Response:
        raise httpx.ConnectError("refused", request=request)

    with pytest.raises(a.APIConnectionError) as caught:
        make_client(handler, max_retries=0).get_user("lin")
    assert not isinstance(caught.value, a.APITimeoutError)
    assert caught.value.request.url.path == "/v1/users/lin"
    assert isinstance(caught.value.__cause__, httpx.ConnectError)
