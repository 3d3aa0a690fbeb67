"""The offline outbox: reports the service cannot take now wait in a SQLite file and arrive
later, in order and exactly once."""

from __future__ import annotations

import sqlite3
import threading
import time
from pathlib import Path

import attune_client as a
import httpx
import pytest
from attune_client._outbox import Outbox
from attune_client_fakes import FakeService, MakeAsyncClient, MakeClient


def outcome(client: a.Client, n: int) -> a.OutcomeResult | a.Queued:
    return client.report_outcome(f"ep_{n % 2}", decision_id=f"dec_{n}", response="accepted")


def feedback(client: a.Client, n: int) -> a.FeedbackResult | a.Queued:
    return client.send_feedback(f"ep_{n % 2}", feedback_id=f"fb_{n}", feedback="positive")


class TestQueueing:
    def test_without_an_outbox_failures_raise(
        self, make_client: MakeClient, service: FakeService
    ) -> None:
        service.down = True
        client = make_client()
        with pytest.raises(a.APIConnectionError):
            outcome(client, 1)
        assert client.pending() == []
        assert client.flush() == a.FlushReport()

    def test_offline_reports_are_queued_in_order(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path, sleeps: list[float]
    ) -> None:
        client = make_client(outbox=outbox_path, max_retries=2)
        service.down = True
        first = outcome(client, 1)
        assert first == a.Queued(kind="outcome", episode_id="ep_1", key="dec_1", position=1)
        assert len(sleeps) == 2  # the first report used the retries
        assert client.pending()[0].attempts == 3
        second = feedback(client, 2)
        assert second == a.Queued(kind="feedback", episode_id="ep_0", key="fb_2", position=2)
        pending = client.pending()
        assert [(p.kind, p.key) for p in pending] == [("outcome", "dec_1"), ("feedback", "fb_2")]
        assert pending[0].body == {"decision_id": "dec_1", "response": "accepted"}
        assert pending[0].attempts == 4  # one more: the try before the second report
        assert "refused" in (pending[0].last_error or "")
        assert pending[0].seq < pending[1].seq
        assert service.applied == []

    @pytest.mark.parametrize("status", [408, 429, 500, 502, 503, 504])
    def test_retryable_statuses_are_queued_too(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path, status: int
    ) -> None:
        service.script = [status] * 4
        result = outcome(make_client(outbox=outbox_path), 1)
        assert isinstance(result, a.Queued)

    @pytest.mark.parametrize(
        ("status", "cls"),
        [(409, a.ConflictError), (422, a.UnprocessableEntityError), (401, a.AuthenticationError)],
    )
    def test_a_report_refused_at_once_raises(
        self,
        make_client: MakeClient,
        service: FakeService,
        outbox_path: Path,
        status: int,
        cls: type[a.APIStatusError],
    ) -> None:
        service.refuse["dec_1"] = status
        client = make_client(outbox=outbox_path)
        with pytest.raises(cls):
            outcome(client, 1)
        assert client.pending() == []

    def test_the_same_report_queued_twice_is_one_entry(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        outcome(client, 1)
        feedback(client, 2)
        again = outcome(client, 1)
        assert again == a.Queued(kind="outcome", episode_id="ep_1", key="dec_1", position=1)
        assert len(client.pending()) == 2

    def test_start_episode_is_never_queued(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        with pytest.raises(a.APIConnectionError):
            client.start_episode(
                "lin", event_id="e1", situation="busy", occurred_at="2026-11-22T15:10:00+08:00"
            )
        assert client.pending() == []


class TestDelivery:
    def test_flush_delivers_in_order_with_the_answers(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        for n in range(1, 6):
            (outcome if n % 2 else feedback)(client, n)
        service.down = False
        report = client.flush()
        expected = [
            ("outcome", "dec_1"),
            ("feedback", "fb_2"),
            ("outcome", "dec_3"),
            ("feedback", "fb_4"),
            ("outcome", "dec_5"),
        ]
        assert service.applied == expected
        assert [(p.kind, p.key) for p, _ in report.delivered] == expected
        entry, answer = report.delivered[0]
        assert isinstance(answer, a.OutcomeResult)
        assert answer.decision is not None
        assert answer.decision.decision_id == "next-dec_1"
        assert isinstance(report.delivered[1][1], a.FeedbackResult)
        assert report.rejected == []
        assert report.remaining == 0
        assert client.pending() == []
        assert client.flush() == a.FlushReport()

    def test_the_next_call_delivers_first(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        outcome(client, 1)
        feedback(client, 2)
        service.down = False
        service.requests.clear()
        assert client.get_user("lin").user_id == "lin"
        assert [r.url.path for r in service.requests] == [
            "/v1/episodes/ep_1/outcomes",
            "/v1/episodes/ep_0/feedback",
            "/v1/users/lin",
        ]
        assert client.pending() == []
        # what was delivered on the way is in the next flush report
        report = client.flush()
        assert [p.key for p, _ in report.delivered] == ["dec_1", "fb_2"]

    def test_a_new_report_goes_behind_the_waiting_ones(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        outcome(client, 1)
        service.down = False
        service.script = [503]  # the head still cannot get through before this call
        queued = feedback(client, 2)
        assert queued == a.Queued(kind="feedback", episode_id="ep_0", key="fb_2", position=2)
        assert service.applied == []
        outcome(client, 3)  # the next call delivers both, then sends its own
        assert service.applied == [("outcome", "dec_1"), ("feedback", "fb_2"), ("outcome", "dec_3")]

    def test_a_report_sent_directly_when_the_queue_is_empty(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_client(outbox=outbox_path)
        result = outcome(client, 1)
        assert isinstance(result, a.OutcomeResult)
        assert service.applied == [("outcome", "dec_1")]
        assert client.pending() == []

    def test_flush_stops_at_a_report_that_cannot_get_through(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_client(outbox=outbox_path, max_retries=1)
        service.down = True
        outcome(client, 1)
        outcome(client, 2)
        report = client.flush()
        assert report.delivered == []
        assert report.remaining == 2
        head, second = client.pending()
        assert head.attempts == 2 + 1 + 2  # when queued, before the second report, by flush
        assert second.attempts == 0  # queued behind: never tried

    def test_calls_while_offline_leave_the_queue_alone(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        outcome(client, 1)
        with pytest.raises(a.APIConnectionError):
            client.get_user("lin")
        assert not client.health()
        assert [p.key for p in client.pending()] == ["dec_1"]


class TestRejection:
    @pytest.mark.parametrize("status", [404, 409, 413, 422])
    def test_a_refused_report_leaves_the_queue(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path, status: int
    ) -> None:
        client = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        for n in (1, 2, 3):
            outcome(client, n)
        service.down = False
        service.refuse["dec_2"] = status
        report = client.flush()
        assert service.applied == [("outcome", "dec_1"), ("outcome", "dec_3")]
        assert [p.key for p, _ in report.delivered] == ["dec_1", "dec_3"]
        [(entry, why)] = report.rejected
        assert entry.key == "dec_2"
        assert why.status_code == status
        assert why.error == "Refused"
        assert why.detail == "dec_2 refused"
        assert client.pending() == []
        [(kept, reason)] = client.rejected()
        assert kept == entry
        assert reason.status_code == status

    def test_an_unusable_key_keeps_the_queue(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        outcome(client, 1)
        service.down = False
        service.refuse["dec_1"] = 401
        with pytest.raises(a.AuthenticationError):
            client.flush()
        assert [p.key for p in client.pending()] == ["dec_1"]
        assert client.rejected() == []
        del service.refuse["dec_1"]
        assert [p.key for p, _ in client.flush().delivered] == ["dec_1"]


class TestInterruptedEpisodes:
    """A mission change interrupts open episodes: their outcomes get a 409 for good."""

    def test_sent_directly_it_raises_at_once(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path, sleeps: list[float]
    ) -> None:
        service.interrupted.add("ep_1")
        client = make_client(outbox=outbox_path)
        with pytest.raises(a.EpisodeInterruptedError) as caught:
            outcome(client, 1)
        assert isinstance(caught.value, a.ConflictError)  # what callers caught before
        assert caught.value.status_code == 409
        assert "interrupted" in caught.value.detail
        assert len(service.posts) == 1  # not retried
        assert sleeps == []
        assert client.pending() == []

    def test_queued_it_leaves_the_queue_and_is_reported(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        for n in (1, 2, 3):
            outcome(client, n)  # dec_1 and dec_3 on ep_1, dec_2 on ep_0
        feedback(client, 5)  # feedback on an interrupted episode is still taken
        service.down = False
        service.interrupted.add("ep_1")  # the fleet's mission changed meanwhile
        report = client.flush()
        assert [p.key for p in report.interrupted] == ["dec_1", "dec_3"]
        assert [p.key for p, _ in report.rejected] == ["dec_1", "dec_3"]
        for _, why in report.rejected:
            assert why.interrupted
            assert why.status_code == 409
        assert [p.key for p, _ in report.delivered] == ["dec_2", "fb_5"]
        assert report.remaining == 0
        assert client.pending() == []
        kept = client.rejected()
        assert [(p.key, why.interrupted) for p, why in kept] == [("dec_1", True), ("dec_3", True)]
        # final: never sent again, by flush or by the next call
        posts = len(service.posts)
        assert client.flush() == a.FlushReport()
        client.get_user("lin")
        assert len(service.posts) == posts

    def test_another_conflict_is_not_an_interruption(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        outcome(client, 1)
        service.down = False
        service.refuse["dec_1"] = 409
        report = client.flush()
        [(_, why)] = report.rejected
        assert not why.interrupted
        assert report.interrupted == []
        with pytest.raises(a.ConflictError) as caught:
            outcome(client, 1)
        assert not isinstance(caught.value, a.EpisodeInterruptedError)

    @pytest.mark.anyio
    async def test_the_async_client_too(
        self, make_async_client: MakeAsyncClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_async_client(outbox=outbox_path, max_retries=0)
        service.down = True
        await client.report_outcome("ep_1", decision_id="dec_1", response="accepted")
        service.down = False
        service.interrupted.add("ep_1")
        report = await client.flush()
        assert [p.key for p in report.interrupted] == ["dec_1"]
        assert await client.pending() == []
        with pytest.raises(a.EpisodeInterruptedError):
            await client.report_outcome("ep_1", decision_id="dec_9", response="accepted")


class TestDurability:
    def test_the_queue_survives_a_restart(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        robot = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        outcome(robot, 1)
        feedback(robot, 2)
        robot.close()
        service.down = False
        again = make_client(outbox=outbox_path)
        assert [p.key for p in again.pending()] == ["dec_1", "fb_2"]
        report = again.flush()
        assert [p.key for p, _ in report.delivered] == ["dec_1", "fb_2"]
        assert service.applied == [("outcome", "dec_1"), ("feedback", "fb_2")]

    def test_a_crash_between_send_and_delete_only_replays(
        self,
        make_client: MakeClient,
        service: FakeService,
        outbox_path: Path,
        monkeypatch: pytest.MonkeyPatch,
    ) -> None:
        robot = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        outcome(robot, 1)
        feedback(robot, 2)
        service.down = False
        service.requests.clear()

        class Crash(BaseException):
            pass

        def crash(self: Outbox, seq: int) -> None:
            raise Crash

        with monkeypatch.context() as patch:
            patch.setattr(Outbox, "remove", crash)
            with pytest.raises(Crash):
                robot.flush()
        assert service.applied == [("outcome", "dec_1")]  # the service took it...
        robot.close()

        again = make_client(outbox=outbox_path)
        assert [p.key for p in again.pending()] == ["dec_1", "fb_2"]  # ...the file kept it
        report = again.flush()
        assert [(p.key, r.replayed) for p, r in report.delivered] == [
            ("dec_1", True),
            ("fb_2", False),
        ]
        assert service.applied == [("outcome", "dec_1"), ("feedback", "fb_2")]
        sent = [r.content for r in service.posts if r.url.path.endswith("outcomes")]
        assert len(sent) == 2
        assert sent[0] == sent[1]

    def test_the_file_is_sqlite_in_wal_mode(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        outcome(client, 1)
        with sqlite3.connect(outbox_path) as conn:
            assert conn.execute("PRAGMA journal_mode").fetchone() == ("wal",)
            assert conn.execute("SELECT key FROM outbox").fetchall() == [("dec_1",)]

    def test_two_clients_on_one_file_never_send_a_report_twice(
        self, make_client: MakeClient, service: FakeService, outbox_path: Path
    ) -> None:
        robot = make_client(outbox=outbox_path, max_retries=0)
        service.down = True
        for n in range(12):
            (outcome if n % 3 else feedback)(robot, n)
        service.down = False
        service.requests.clear()
        service.on_request = lambda request: time.sleep(0.01)  # let the flushes overlap
        others = [make_client(outbox=outbox_path) for _ in range(2)]
        reports: list[a.FlushReport] = []
        threads = [
            threading.Thread(target=lambda c=c: reports.append(c.flush())) for c in (*others, robot)
        ]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(timeout=30)
        keys = [f"fb_{n}" if n % 3 == 0 else f"dec_{n}" for n in range(12)]
        assert [key for _, key in service.applied] == keys
        assert len(service.posts) == 12  # each sent once
        assert sorted(p.key for r in reports for p, _ in r.delivered) == sorted(keys)
        assert robot.pending() == []


class TestAsyncOutbox:
    @pytest.mark.anyio
    async def test_queue_then_deliver_in_order(
        self, make_async_client: MakeAsyncClient, service: FakeService, outbox_path: Path
    ) -> None:
        client = make_async_client(outbox=outbox_path, max_retries=1)
        service.down = True
        first = await client.report_outcome("ep_1", decision_id="dec_1", response="accepted")
        second = await client.send_feedback("ep_1", feedback_id="fb_1", feedback="negative")
        assert first == a.Queued(kind="outcome", episode_id="ep_1", key="dec_1", position=1)
        assert isinstance(second, a.Queued)
        assert second.position == 2
        assert [p.key for p in await client.pending()] == ["dec_1", "fb_1"]
        service.down = False
        service.script = [503]
        third = await client.report_outcome("ep_2", decision_id="dec_2", response="none")
        assert isinstance(third, a.Queued)
        assert third.position == 3
        report = await client.flush()
        assert [p.key for p, _ in report.delivered] == ["dec_1", "fb_1", "dec_2"]
        assert service.applied == [("outcome", "dec_1"), ("feedback", "fb_1"), ("outcome", "dec_2")]
        assert await client.pending() == []

    @pytest.mark.anyio
    async def test_rejections_and_restart(
        self, make_async_client: MakeAsyncClient, service: FakeService, outbox_path: Path
    ) -> None:
        robot = make_async_client(outbox=outbox_path, max_retries=0)
        service.down = True
        await robot.report_outcome("ep_1", decision_id="dec_1", response="accepted")
        await robot.report_outcome("ep_1", decision_id="dec_2", response="accepted")
        await robot.aclose()
        service.down = False
        service.refuse["dec_1"] = 409
        again = make_async_client(outbox=outbox_path)
        user = await again.get_user("lin")  # delivers first
        assert user.user_id == "lin"
        report = await again.flush()
        assert [p.key for p, _ in report.rejected] == ["dec_1"]
        assert [p.key for p, _ in report.delivered] == ["dec_2"]
        assert [p.key for p, _ in await again.rejected()] == ["dec_1"]

    @pytest.mark.anyio
    async def test_without_an_outbox(
        self, make_async_client: MakeAsyncClient, service: FakeService
    ) -> None:
        service.down = True
        client = make_async_client(max_retries=0)
        with pytest.raises(a.APIConnectionError):
            await client.send_feedback("ep_1", feedback_id="fb", feedback="positive")
        assert await client.pending() == []
        assert await client.flush() == a.FlushReport()


def test_a_connect_error_is_an_httpx_transport_error() -> None:
    # the outbox relies on every network failure being one of these
    assert issubclass(httpx.ConnectError, httpx.TransportError)
    assert issubclass(httpx.ReadTimeout, httpx.TransportError)
