"""The client against a real ``attune serve`` process: the contract over HTTP, and the outbox
acceptance test with a robot process that outlives a service outage and its own restart."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import attune_client as a
import httpx
import pytest

from app.db.session import Database
from app.services.auth import create_key
from app.settings import Settings
from tests.support.live import LiveService, fresh_database
from tests.support.people import cooperative

from .helpers import EVENT_TIME

pytestmark = pytest.mark.live

ROBOT = Path(__file__).with_name("robot.py")


@pytest.fixture(params=["sqlite", "postgresql"])
def live(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[LiveService]:
    """A running ``attune serve`` on a fresh database of each engine."""
    with (
        fresh_database(request.param, tmp_path) as url,
        LiveService(url, log_path=tmp_path / "serve.log") as service,
    ):
        yield service


def keys(live: LiveService, *roles: str) -> list[str]:
    """New keys of these roles in the live service's database (what ``attune keys create``
    does, without starting a process per key)."""
    database = Database(Settings(database_url=live.database_url, _env_file=None))  # type: ignore[call-arg]
    try:
        with database.transaction() as session:
            return [create_key(session, role=role)[1] for role in roles]
    finally:
        database.dispose()


def quick(client: a.Client) -> a.Client:
    from attune_client._retry import Backoff

    client._backoff = Backoff(initial=0.01, maximum=0.05)
    return client


@pytest.mark.parametrize("live", ["postgresql"], indirect=True)
def test_the_contract_over_http(live: LiveService) -> None:
    """Every kind of call once over real HTTP (the in-process tests cover both engines)."""
    robot_key, admin_key = keys(live, "robot", "admin")
    timeout = httpx.Timeout(10.0, connect=2.0)
    with (
        quick(a.Client(live.url, robot_key, timeout=timeout)) as robot,
        quick(a.Client(live.url, admin_key, timeout=timeout)) as admin,
    ):
        assert robot.health()
        assert robot.ready()
        assert robot.mission().name == "office"
        assert robot.put_user("lin", display_name="Mrs. Lin").display_name == "Mrs. Lin"
        started = robot.start_episode(
            "lin", event_id="e1", occurred_at=EVENT_TIME, situation="stretching", robot_id="robot7"
        )
        assert robot.start_episode(
            "lin", event_id="e1", occurred_at=EVENT_TIME, situation="stretching", robot_id="robot7"
        ).replayed
        decision, n = started.decision, 0
        while decision is not None:
            kwargs = cooperative(decision.action, n)
            result = robot.report_outcome(
                started.episode_id, decision_id=decision.decision_id, **kwargs
            )
            again = robot.report_outcome(
                started.episode_id, decision_id=decision.decision_id, **kwargs
            )
            assert isinstance(result, a.OutcomeResult)
            assert isinstance(again, a.OutcomeResult)
            assert again.replayed
            assert not result.replayed
            decision, n = result.decision, n + 1
        fb = robot.send_feedback(started.episode_id, feedback_id="fb1", feedback="positive")
        assert isinstance(fb, a.FeedbackResult)
        trace = robot.get_episode(started.episode_id)
        assert trace.status == "closed"
        assert len(trace.decisions) == n
        assert [f.feedback_id for f in trace.feedback] == ["fb1"]
        assert [e.episode_id for e in robot.iter_episodes("lin")] == [started.episode_id]
        assert [u.user_id for u in robot.iter_users()] == ["lin"]
        assert robot.get_stats("lin").episodes == 1
        version = robot.get_model("lin").version
        document = admin.export_model("lin")
        admin.reset_model("lin")
        assert robot.get_model("lin").version == version + 1
        assert admin.import_model("lin", document).algorithm == "dts-routine"

        # each error the service produces, as its class
        with a.Client(live.url, "att_unknown") as stranger, pytest.raises(a.AuthenticationError):
            stranger.get_user("lin")
        with pytest.raises(a.PermissionDeniedError):
            robot.delete_user("lin")
        with pytest.raises(a.NotFoundError):
            robot.get_episode("ep_absent")
        with pytest.raises(a.ConflictError):
            robot.start_episode("lin", event_id="e1", occurred_at=EVENT_TIME, situation="busy")
        with pytest.raises(a.PayloadTooLargeError):
            robot.put_user("lin", display_name="x" * 70_000)
        with pytest.raises(a.UnprocessableEntityError) as invalid:
            robot.start_episode("lin", event_id="e2", occurred_at=EVENT_TIME, situation="dancing")
        assert "stretching" in invalid.value.detail
        admin.delete_user("lin")
        with pytest.raises(a.NotFoundError):
            robot.get_user("lin")


# -- the outbox acceptance test ---------------------------------------------------------------
class Journal:
    """The robot's journal, read as it grows."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def lines(self) -> list[dict[str, Any]]:
        if not self.path.exists():
            return []
        out = []
        for raw in self.path.read_text().splitlines():
            try:
                out.append(json.loads(raw))
            except json.JSONDecodeError:  # the robot may be writing it (or was killed)
                continue
        return out

    def count(self, **match: Any) -> int:
        return sum(1 for line in self.lines() if all(line.get(k) == v for k, v in match.items()))


def wait_for(
    condition: Callable[[], bool],
    robot: subprocess.Popen[bytes],
    what: str,
    log: Path,
    timeout: float = 60,
) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if robot.poll() is not None:
            pytest.fail(
                f"the robot exited ({robot.returncode}) before {what}:\n{log.read_text()[-3000:]}"
            )
        if time.monotonic() > deadline:
            pytest.fail(f"no {what} within {timeout} s:\n{log.read_text()[-3000:]}")
        time.sleep(0.02)


def service_history(client: a.Client) -> list[tuple[Any, str, str]]:
    """Every report the service stored, as (time it took it, kind, key), oldest first."""
    history = []
    for user in client.iter_users():
        for summary in client.iter_episodes(user.user_id):
            trace = client.get_episode(summary.episode_id)
            history += [
                (d.answered_at, "outcome", d.decision_id)
                for d in trace.decisions
                if d.answered_at is not None
            ]
            history += [(f.received_at, "feedback", f.feedback_id) for f in trace.feedback]
    return sorted(history)


def test_reports_survive_a_service_outage_and_a_robot_restart(
    live: LiveService, tmp_path: Path
) -> None:
    """The service is stopped mid-run while a simulated robot keeps reporting; after it
    restarts, every report arrives exactly once and in order (checked against the service's
    history), including after the robot process itself was restarted."""
    key, admin_key = keys(live, "robot", "admin")
    folder = tmp_path / "robot"
    folder.mkdir()
    log = tmp_path / "robot.log"
    journal = Journal(folder / "journal.jsonl")

    def spawn() -> subprocess.Popen[bytes]:
        with open(log, "ab") as out:
            return subprocess.Popen(
                [
                    sys.executable,
                    str(ROBOT),
                    "--url",
                    live.url,
                    "--key",
                    key,
                    "--dir",
                    str(folder),
                    "--episodes",
                    "5",
                ],
                stdout=out,
                stderr=subprocess.STDOUT,
            )

    def hold_while_decisions_are_open() -> None:
        """Pause the robot between rounds at a moment when at least two people have a
        decision to answer (so the outage catches outcomes, not only feedback)."""
        for _ in range(200):
            held = journal.count(type="held")
            hold.touch()
            wait_for(
                lambda held=held: journal.count(type="held") > held,  # type: ignore[misc]
                robot,
                "the robot holding",
                log,
            )
            state_file = folder / "state.json"
            if state_file.exists():
                state = json.loads(state_file.read_text())
                open_decisions = sum(1 for p in state["users"].values() if p["decision"])
                if open_decisions >= 2 and journal.count(op="outcome", status="sent") >= 6:
                    return
            hold.unlink()
            time.sleep(0.03)
        pytest.fail("the robot never had two decisions open at once")

    hold = folder / "hold"
    robot = spawn()
    try:
        hold_while_decisions_are_open()
        live.stop()  # the service goes away mid-run...
        hold.unlink()  # ...while the robot goes on reporting
        wait_for(
            lambda: journal.count(op="outcome", status="queued") >= 2,
            robot,
            "outcomes queued while the service is down",
            log,
        )
        robot.kill()  # SIGKILL, wherever it is
        robot.wait(timeout=10)
        robot = spawn()  # the same robot, from its state, journal and outbox
        wait_for(
            lambda: journal.count(status="queued", run=2) >= 2,
            robot,
            "reports queued by the restarted robot",
            log,
        )
        live.start()
        assert robot.wait(timeout=90) == 0, log.read_text()[-3000:]
    finally:
        if robot.poll() is None:
            robot.kill()
            robot.wait(timeout=10)

    lines = journal.lines()
    assert lines[-1]["type"] == "done"
    assert lines[-1]["rejected"] == 0
    boots = [line for line in lines if line["type"] == "boot"]
    assert boots[1]["pending"] >= 1  # the restarted robot found its outbox full
    # every report the robot made, in the order it made them (a redone intent counts once)
    made: dict[int, tuple[str, str]] = {}
    for line in lines:
        if line["type"] == "intent" and line["op"] in ("outcome", "feedback"):
            key_name = "decision_id" if line["op"] == "outcome" else "feedback_id"
            made.setdefault(line["i"], (line["op"], line["args"][key_name]))
    robot_order = [made[i] for i in sorted(made)]
    assert len(set(robot_order)) == len(robot_order)

    with a.Client(live.url, admin_key) as admin:
        stored = [(kind, k) for _, kind, k in service_history(admin)]
        assert stored == robot_order  # each exactly once, in the robot's order
        # and each counted once by the learners: one model version per outcome and feedback
        for user in admin.iter_users():
            traces = [admin.get_episode(e.episode_id) for e in admin.iter_episodes(user.user_id)]
            writes = sum(
                len([d for d in t.decisions if d.answered_at]) + len(t.feedback) for t in traces
            )
            assert admin.get_model(user.user_id).version == writes
            assert all(t.status == "closed" for t in traces)
    queued = journal.count(status="queued")
    assert queued >= 2
    with a.Client(live.url, key, outbox=folder / "outbox.db") as robot_client:
        assert robot_client.pending() == []
        assert robot_client.rejected() == []
