"""Which failures are retried, how often, how long the client waits, and that every retry
sends the very same request."""

from __future__ import annotations

import datetime as dt
import email.utils
import time
from collections.abc import Callable

import attune_client as a
import httpx
import pytest
from attune_client._retry import Backoff, parse_retry_after
from attune_client_fakes import FakeService, MakeAsyncClient, MakeClient


def scripted(
    *steps: int | httpx.TransportError | tuple[int, dict[str, str]],
) -> tuple[list[httpx.Request], Callable[[httpx.Request], httpx.Response]]:
    """A handler that answers the steps in turn, then 200 with a user."""
    seen: list[httpx.Request] = []
    queue = list(steps)

    def handler(request: httpx.Request) -> httpx.Response:
        seen.append(request)
        if queue:
            step = queue.pop(0)
            if isinstance(step, httpx.TransportError):
                raise step
            status, headers = step if isinstance(step, tuple) else (step, {})
            return httpx.Response(
                status, headers=headers, json={"error": "Scripted", "detail": f"{status}"}
            )
        return FakeService().handler(request)

    return seen, handler


def connect_error() -> httpx.ConnectError:
    return httpx.ConnectError("connection refused")


class TestWhatIsRetried:
    def test_a_connection_error_then_success(
        self, make_client: MakeClient, sleeps: list[float]
    ) -> None:
        seen, handler = scripted(connect_error())
        user = make_client(handler).get_user("lin")
        assert user.user_id == "lin"
        assert len(seen) == 2
        assert len(sleeps) == 1

    def test_read_timeouts_are_retried_then_raise_a_timeout_error(
        self, make_client: MakeClient, sleeps: list[float]
    ) -> None:
        seen, handler = scripted(*[httpx.ReadTimeout("slow") for _ in range(10)])
        with pytest.raises(a.APITimeoutError):
            make_client(handler, max_retries=2).get_user("lin")
        assert len(seen) == 3
        assert len(sleeps) == 2

    def test_a_read_timeout_then_success(self, make_client: MakeClient) -> None:
        seen, handler = scripted(httpx.ReadTimeout("slow"))
        assert make_client(handler).get_user("lin").user_id == "lin"
        assert len(seen) == 2

    @pytest.mark.parametrize("status", [408, 429, 500, 502, 503, 504])
    def test_retried_statuses(
        self, make_client: MakeClient, sleeps: list[float], status: int
    ) -> None:
        seen, handler = scripted(status, status)
        assert make_client(handler).get_user("lin").user_id == "lin"
        assert len(seen) == 3
        assert len(sleeps) == 2

    @pytest.mark.parametrize(
        ("status", "cls"),
        [
            (400, a.BadRequestError),
            (401, a.AuthenticationError),
            (403, a.PermissionDeniedError),
            (404, a.NotFoundError),
            (409, a.ConflictError),
            (413, a.PayloadTooLargeError),
            (422, a.UnprocessableEntityError),
            (501, a.InternalServerError),
        ],
    )
    def test_other_errors_are_not_retried(
        self, make_client: MakeClient, sleeps: list[float], status: int, cls: type[a.APIStatusError]
    ) -> None:
        seen, handler = scripted(status)
        with pytest.raises(cls) as caught:
            make_client(handler).get_user("lin")
        assert caught.value.error == "Scripted"
        assert caught.value.detail == str(status)
        assert len(seen) == 1
        assert sleeps == []

    @pytest.mark.parametrize("retries", [0, 1, 3, 5])
    def test_retries_are_bounded(
        self, make_client: MakeClient, sleeps: list[float], retries: int
    ) -> None:
        seen, handler = scripted(*[503] * 20)
        with pytest.raises(a.ServiceUnavailableError):
            make_client(handler, max_retries=retries).get_user("lin")
        assert len(seen) == retries + 1
        assert len(sleeps) == retries

    def test_the_default_is_three_retries(self, make_client: MakeClient) -> None:
        seen, handler = scripted(*[connect_error() for _ in range(20)])
        with pytest.raises(a.APIConnectionError):
            make_client(handler).get_user("lin")
        assert a.DEFAULT_MAX_RETRIES == 3
        assert len(seen) == 4

    def test_a_negative_retry_count_is_refused(self) -> None:
        with pytest.raises(ValueError, match="max_retries"):
            a.Client("http://x", "k", max_retries=-1)

    def test_every_attempt_sends_the_same_request(
        self, make_client: MakeClient, service: FakeService
    ) -> None:
        service.script = [connect_error(), 503, httpx.ReadTimeout("slow"), 502]
        client = make_client(service.handler, max_retries=4)
        result = client.report_outcome(
            "ep_1", decision_id="dec_1", response="accepted", feedback="positive"
        )
        assert isinstance(result, a.OutcomeResult)
        posts = service.posts
        assert len(posts) == 5
        assert len({p.content for p in posts}) == 1
        assert len({p.url for p in posts}) == 1
        assert b'"decision_id":"dec_1"' in posts[0].content
        assert service.applied == [("outcome", "dec_1")]

    def test_an_answer_lost_on_the_way_is_replayed_not_counted_twice(
        self, make_client: MakeClient, service: FakeService
    ) -> None:
        # The service applied the first attempt, but its answer never arrived.
        first = True

        def handler(request: httpx.Request) -> httpx.Response:
            nonlocal first
            response = service.handler(request)
            if first:
                first = False
                raise httpx.ReadError("connection reset")
            return response

        result = make_client(handler).send_feedback("ep_1", feedback_id="fb-1", feedback="positive")
        assert isinstance(result, a.FeedbackResult)
        assert result.replayed
        assert service.applied == [("feedback", "fb-1")]


class TestHowLongItWaits:
    def test_backoff_doubles_up_to_the_cap(self) -> None:
        backoff = Backoff()
        delays = [backoff.delay(n, None, lambda: 0.0) for n in range(7)]
        assert delays == [0.5, 1.0, 2.0, 4.0, 8.0, 8.0, 8.0]

    @pytest.mark.parametrize("draw", [0.0, 0.3, 0.999999])
    def test_jitter_shortens_by_at_most_a_quarter(self, draw: float) -> None:
        backoff = Backoff()
        for attempt in range(6):
            base = min(0.5 * 2**attempt, 8.0)
            delay = backoff.delay(attempt, None, lambda: draw)
            assert 0.75 * base <= delay <= base
            assert delay == pytest.approx(base * (1 - 0.25 * draw))

    def test_the_client_waits_with_growing_jittered_delays(
        self, make_client: MakeClient, sleeps: list[float]
    ) -> None:
        seen, handler = scripted(*[connect_error() for _ in range(20)])
        client = make_client(handler, max_retries=6)
        client._random = lambda: 0.5
        with pytest.raises(a.APIConnectionError):
            client.get_user("lin")
        assert sleeps == pytest.approx([b * 0.875 for b in (0.5, 1, 2, 4, 8, 8)])

    def test_real_jitter_stays_in_bounds(
        self, make_client: MakeClient, sleeps: list[float]
    ) -> None:
        seen, handler = scripted(*[500] * 50)
        with pytest.raises(a.InternalServerError):
            make_client(handler, max_retries=6).get_user("lin")
        for attempt, delay in enumerate(sleeps):
            base = min(0.5 * 2**attempt, 8.0)
            assert 0.75 * base <= delay <= base

    def test_retry_after_in_seconds(self, make_client: MakeClient, sleeps: list[float]) -> None:
        seen, handler = scripted((429, {"Retry-After": "2"}), (503, {"Retry-After": "0.25"}))
        assert make_client(handler).get_user("lin").user_id == "lin"
        assert sleeps == [2.0, 0.25]

    def test_retry_after_as_an_http_date(
        self, make_client: MakeClient, sleeps: list[float]
    ) -> None:
        when = email.utils.formatdate(time.time() + 30, usegmt=True)
        seen, handler = scripted((429, {"Retry-After": when}))
        assert make_client(handler).get_user("lin").user_id == "lin"
        assert len(sleeps) == 1
        assert 28.0 <= sleeps[0] <= 30.0

    def test_retry_after_is_capped(self, make_client: MakeClient, sleeps: list[float]) -> None:
        seen, handler = scripted((429, {"Retry-After": "3600"}))
        make_client(handler).get_user("lin")
        assert sleeps == [60.0]

    def test_an_unreadable_retry_after_falls_back_to_the_backoff(
        self, make_client: MakeClient, sleeps: list[float]
    ) -> None:
        seen, handler = scripted((429, {"Retry-After": "soon"}))
        client = make_client(handler)
        client._random = lambda: 0.0
        client.get_user("lin")
        assert sleeps == [0.5]

    def test_parse_retry_after(self) -> None:
        now = dt.datetime(2026, 11, 22, 9, 30, tzinfo=dt.UTC).timestamp()
        assert parse_retry_after("120", now=now) == 120.0
        assert parse_retry_after("Sun, 22 Nov 2026 09:30:05 GMT", now=now) == 5.0
        assert parse_retry_after("Sun, 22 Nov 2026 09:29:00 GMT", now=now) == 0.0
        assert parse_retry_after("-3", now=now) == 0.0
        assert parse_retry_after(None) is None
        assert parse_retry_after("later") is None
        assert parse_retry_after("nan") is None


class TestTimeouts:
    def test_the_default_timeout_is_explicit(self) -> None:
        assert httpx.Timeout(10.0, connect=3.0) == a.DEFAULT_TIMEOUT
        with a.Client("http://attune.test", "k") as client:
            assert client.timeout == a.DEFAULT_TIMEOUT

    def test_every_request_carries_the_timeout(self, make_client: MakeClient) -> None:
        seen, handler = scripted()
        make_client(handler).get_user("lin")
        assert seen[0].extensions["timeout"] == {
            "connect": 3.0,
            "read": 10.0,
            "write": 10.0,
            "pool": 10.0,
        }

    def test_a_number_sets_every_timeout(self, make_client: MakeClient) -> None:
        seen, handler = scripted()
        make_client(handler, timeout=2.5).get_user("lin")
        assert seen[0].extensions["timeout"] == {
            "connect": 2.5,
            "read": 2.5,
            "write": 2.5,
            "pool": 2.5,
        }


class TestAsync:
    @pytest.mark.anyio
    async def test_a_connection_error_then_success(
        self, make_async_client: MakeAsyncClient, sleeps: list[float]
    ) -> None:
        seen, handler = scripted(connect_error())
        user = await make_async_client(handler).get_user("lin")
        assert user.user_id == "lin"
        assert len(seen) == 2
        assert len(sleeps) == 1

    @pytest.mark.anyio
    async def test_retry_after_and_bounds(
        self, make_async_client: MakeAsyncClient, sleeps: list[float]
    ) -> None:
        seen, handler = scripted(*[(429, {"Retry-After": "3"})] * 10)
        with pytest.raises(a.RateLimitError) as caught:
            await make_async_client(handler, max_retries=2).get_user("lin")
        assert caught.value.retry_after == 3.0
        assert sleeps == [3.0, 3.0]
        assert len(seen) == 3

    @pytest.mark.anyio
    async def test_timeouts_become_timeout_errors(self, make_async_client: MakeAsyncClient) -> None:
        seen, handler = scripted(*[httpx.ConnectTimeout("slow") for _ in range(5)])
        with pytest.raises(a.APITimeoutError):
            await make_async_client(handler, max_retries=1).get_user("lin")
        assert len(seen) == 2

    @pytest.mark.anyio
    @pytest.mark.parametrize("status", [400, 401, 403, 404, 409, 413, 422])
    async def test_client_errors_are_not_retried(
        self, make_async_client: MakeAsyncClient, status: int
    ) -> None:
        seen, handler = scripted(status)
        with pytest.raises(a.APIStatusError) as caught:
            await make_async_client(handler).get_user("lin")
        assert caught.value.status_code == status
        assert len(seen) == 1

    @pytest.mark.anyio
    async def test_every_attempt_sends_the_same_request(
        self, make_async_client: MakeAsyncClient, service: FakeService
    ) -> None:
        service.script = [503, connect_error(), 504]
        client = make_async_client()
        result = await client.report_outcome("ep_1", decision_id="dec_1", response="accepted")
        assert isinstance(result, a.OutcomeResult)
        assert len(service.posts) == 4
        assert len({p.content for p in service.posts}) == 1
        assert service.applied == [("outcome", "dec_1")]

    @pytest.mark.anyio
    async def test_the_default_timeout(self) -> None:
        async with a.AsyncClient("http://attune.test", "k") as client:
            assert client.timeout == a.DEFAULT_TIMEOUT
