"""Acceptance: simulated users (docs/method.md §11) driven through the HTTP API.

Each simulated person lives through a seeded event stream whose needs drift half-way; the test
plays the person (``respond``) against the service's decisions, records what it saw, and then
checks that the service's stats, traces and model agree with that record, and that
``attune models rebuild`` replays every user's history into the identical model.
"""

from __future__ import annotations

import datetime as dt
import itertools
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select

from app.db.models import Decision, Episode
from app.db.session import Database
from app.fleet.simulate import state_before
from app.learning import Action, ActionKind, Transition, office_mission, space_for
from app.learning.evaluation import episode_metrics
from app.learning.negotiation import INTERACTION_CODE, interaction_class
from app.learning.simulation import (
    STEP_COLUMNS,
    UserProfile,
    drift,
    event_stream,
    random_profile,
    respond,
)
from app.settings import Settings
from tests.support.commands import rebuild
from tests.support.rows import user_pk

MISSION = office_mission()
SPACE = space_for(MISSION)
REWARDS = MISSION.rewards
DAY = dt.date(2026, 11, 2)
OFFSETS = ("+08:00", "-05:00", "+00:00", "+05:30")
QUERY_KINDS = {"query_type", "query_detail"}
TICK = itertools.count(1)  # orders the writes of a test (resets included)


# -- playing the person ------------------------------------------------------------------------
@dataclass
class SeenDecision:
    decision_id: str
    action: dict[str, Any]
    probabilities: list[dict[str, Any]]
    chain: list[dict[str, Any]]
    sent: dict[str, Any] = field(default_factory=dict)  # the outcome body
    reward: float | None = None  # the outcome's reward as answered
    drawn_tick: int = 0  # when the service drew it and when it was answered (TICK order)
    answered_tick: int = 0


@dataclass
class SeenEpisode:
    episode_id: str
    event: int
    context: int
    initiated: bool = False
    interaction: int = 0
    success: bool = False
    queries: int = 0
    reward: float = 0.0  # the last total_reward the service reported for it
    expected_reward: float = 0.0  # the test's own sum: responses, respond steps, feedback
    decisions: list[SeenDecision] = field(default_factory=list)
    feedback: list[dict[str, Any]] = field(default_factory=list)

    @property
    def silent_steps(self) -> int:
        return sum(len(d.chain) for d in self.decisions)


@dataclass
class SimUser:
    user_id: str
    profiles: list[UserProfile]
    change_points: list[int]
    contexts: np.ndarray
    uniforms: np.ndarray
    offset: str
    episodes: list[SeenEpisode] = field(default_factory=list)

    def profile_at(self, event: int) -> UserProfile:
        active = sum(1 for cp in self.change_points if cp <= event) - 1
        return self.profiles[active]


def make_users(
    rng: np.random.Generator, names: list[str], n_events: int, change_at: int
) -> list[SimUser]:
    users = []
    for i, name in enumerate(names):
        before = random_profile(MISSION, rng)
        after = drift(before, MISSION, rng)
        points = [0, change_at]
        contexts = event_stream([before, after], points, MISSION, n_events, rng)
        uniforms = rng.random((n_events, STEP_COLUMNS))
        users.append(
            SimUser(name, [before, after], points, contexts, uniforms, OFFSETS[i % len(OFFSETS)])
        )
    return users


def occurred_at(slot: str, offset: str, event: int) -> str:
    """A time whose *local* clock (at ``offset``) falls in ``slot``: 45 minutes after its start."""
    start = next(s for s in MISSION.time_slots if s.name == slot).start
    local = dt.datetime.combine(DAY + dt.timedelta(days=event), start) + dt.timedelta(minutes=45)
    assert MISSION.slot_at(local.time()) == slot
    return local.strftime("%Y-%m-%dT%H:%M:%S") + offset


def to_action(d: dict[str, Any]) -> Action:
    return Action(ActionKind(d["kind"]), d.get("service"), d.get("detail"))


def chain_reward(chain: list[dict[str, Any]]) -> float:
    return sum(REWARDS.positive for s in chain if s["action"]["kind"] == "respond")


def check_decision(decision: dict[str, Any]) -> None:
    probs = decision["probabilities"]
    assert sum(p["p"] for p in probs) == pytest.approx(1.0)
    assert decision["action"] in [p["action"] for p in probs]


def outcome_body(decision: dict[str, Any], response: str, next_state: int) -> dict[str, Any]:
    body: dict[str, Any] = {"decision_id": decision["decision_id"], "response": response}
    info = SPACE.state_info(next_state)
    if response == "human_request":
        body["service"] = info.service
    elif response == "answered":
        if decision["action"]["kind"] == "query_type":
            body["service"] = info.service
        else:
            body["detail"] = info.detail
    return body


def post_json(
    client: TestClient, url: str, body: dict[str, Any], status: int = 200
) -> dict[str, Any]:
    r = client.post(url, json=body)
    assert r.status_code == status, (url, body, r.status_code, r.text)
    assert "Idempotent-Replay" not in r.headers
    out: dict[str, Any] = r.json()
    return out


def play_event(
    client: TestClient, user: SimUser, e: int, *, after_first_outcome: Any = None
) -> SeenEpisode:
    """One event of ``user``: the episode from its start to its end, the person simulated."""
    context = int(user.contexts[e])
    slot, situation = MISSION.context_names(context)
    profile = user.profile_at(e)
    body = {
        "event_id": f"{user.user_id}-e{e:03d}",
        "occurred_at": occurred_at(slot, user.offset, e),
        "situation": situation,
        "initiator": "robot",
        "request": None,
        "robot_id": "sim-robot",
    }
    ep = post_json(client, f"/v1/users/{user.user_id}/episodes", body, 201)
    drawn = next(TICK)
    assert ep["context"] == {"time_slot": slot, "situation": situation}
    assert ep["status"] == "open"
    assert ep["state"] == "OBSERVE"
    assert ep["total_reward"] == 0.0
    seen = SeenEpisode(ep["episode_id"], e, context)
    rows: list[Transition] = []
    decision: dict[str, Any] | None = ep["decision"]
    step = 0
    while decision is not None:
        assert step < 4, "an episode longer than a negotiation"
        check_decision(decision)
        action = to_action(decision["action"])
        a, s = SPACE.action_index(action), state_before(SPACE, action)
        assert SPACE.is_valid(s, a)
        reaction = respond(SPACE, profile, context, s, a, user.uniforms[e, 2 * step : 2 * step + 2])
        assert reaction.response in decision["expects"]
        sent = outcome_body(decision, reaction.response, reaction.next_state)
        out = post_json(client, f"/v1/episodes/{seen.episode_id}/outcomes", sent)
        answered = next(TICK)
        assert out["reward"] == pytest.approx(reaction.reward)
        seen.decisions.append(
            SeenDecision(
                decision["decision_id"],
                decision["action"],
                decision["probabilities"],
                decision["chain"],
                sent,
                out["reward"],
                drawn,
                answered,
            )
        )
        drawn = answered
        seen.expected_reward += chain_reward(decision["chain"]) + reaction.reward
        rows.append(
            Transition(e + 1, context, s, a, reaction.reward, reaction.next_state, reaction.signal)
        )
        if action.kind is ActionKind.INITIATE:
            seen.initiated = True
        if action.kind is ActionKind.PERFORM and reaction.response == "accepted":
            seen.success = True
        seen.queries += action.kind.value in QUERY_KINDS
        seen.reward = out["episode"]["total_reward"]
        decision = out["decision"]
        if decision is None:
            assert out["episode"]["status"] == "closed"
            assert out["episode"]["state"] == "END"
            assert reaction.next_state == SPACE.END
        else:
            assert out["episode"]["status"] == "open"
            nxt = state_before(SPACE, to_action(decision["action"]))
            assert out["episode"]["state"] == SPACE.state_info(nxt).kind.value
        step += 1
        if step == 1 and after_first_outcome is not None:
            after_first_outcome(seen, decision is None)
    seen.interaction = INTERACTION_CODE[interaction_class(SPACE, rows)]
    assert seen.reward == pytest.approx(seen.expected_reward)
    user.episodes.append(seen)
    return seen


# -- checks ------------------------------------------------------------------------------------
def expected_stats(episodes: list[SeenEpisode]) -> dict[str, Any]:
    reward = np.asarray([ep.expected_reward for ep in episodes], dtype=np.float64)
    m = episode_metrics(
        np.asarray([ep.initiated for ep in episodes], dtype=bool),
        np.asarray([ep.interaction for ep in episodes], dtype=np.int8),
        np.asarray([ep.success for ep in episodes], dtype=bool),
        np.asarray([ep.queries for ep in episodes], dtype=np.int64),
        reward,
    )

    def num(x: float) -> Any:
        return None if np.isnan(x) else pytest.approx(x)

    return {
        "episodes": len(episodes),
        "missions": int(m["missions"]),
        "interaction_rate": num(m["interaction_rate"]),
        "success_rate": num(m["success_rate"]),
        "queries_per_mission": num(m["queries_per_mission"]),
        "total_reward": pytest.approx(m["total_reward"]),
        "cumulative_reward": pytest.approx([0.0, *np.cumsum(reward).tolist()]),
    }


def check_stats(client: TestClient, user: SimUser, last: int | None = None) -> dict[str, Any]:
    url = f"/v1/users/{user.user_id}/stats" + (f"?last={last}" if last else "")
    r = client.get(url)
    assert r.status_code == 200, r.text
    got: dict[str, Any] = r.json()
    window = user.episodes[-last:] if last else user.episodes
    want = expected_stats(window)
    assert {k: got.get(k) for k in want} == want, (user.user_id, last)
    return got


def check_trace(client: TestClient, user: SimUser, seen: SeenEpisode) -> None:
    r = client.get(f"/v1/episodes/{seen.episode_id}")
    assert r.status_code == 200, r.text
    trace = r.json()
    assert trace["user_id"] == user.user_id
    assert trace["event_id"] == f"{user.user_id}-e{seen.event:03d}"
    assert trace["status"] == "closed"
    assert trace["initiator"] == "robot"
    slot, situation = MISSION.context_names(seen.context)
    assert trace["context"] == {"time_slot": slot, "situation": situation}
    klass = {0: "none", 1: "I1", 2: "I2", 3: "I3"}[seen.interaction]
    assert trace["interaction_class"] == klass
    assert trace["total_reward"] == pytest.approx(seen.expected_reward)
    got = [
        (
            d["decision_id"],
            d["action"],
            d["probabilities"],
            d["chain"],
            d["response"],
            d["service"],
            d["detail"],
            d["reward"],
        )
        for d in trace["decisions"]
    ]
    want = [
        (
            d.decision_id,
            d.action,
            d.probabilities,
            d.chain,
            d.sent["response"],
            d.sent.get("service"),
            d.sent.get("detail"),
            d.reward,
        )
        for d in seen.decisions
    ]
    assert got == want
    assert [(f["feedback_id"], f["feedback"], f["reward"]) for f in trace["feedback"]] == [
        (f["feedback_id"], f["feedback"], f["reward"]) for f in seen.feedback
    ]


def model_visits(client: TestClient, user_id: str) -> int:
    r = client.get(f"/v1/users/{user_id}/model")
    assert r.status_code == 200, r.text
    return sum(a["visits"] for c in r.json()["contexts"] for s in c["states"] for a in s["actions"])


def stored_steps(db: Database, user_id: str) -> tuple[int, int, int]:
    """(decisions, answered decisions, silent chain steps) stored for the user."""
    with db.transaction(write=False) as s:
        rows = s.scalars(
            select(Decision)
            .join(Episode, Episode.id == Decision.episode_id)
            .where(Episode.user_pk == user_pk(s, user_id))
        ).all()
        return (
            len(rows),
            sum(d.response is not None for d in rows),
            sum(len(d.chain) for d in rows),
        )


def check_rebuild(settings: Settings, user_id: str, decisions: int) -> None:
    code, summary = rebuild(settings.database_url, user_id, pooler=settings.database_pooler)
    assert summary["identical"] is True, summary
    assert code == 0, summary
    assert summary["mismatched_decisions"] == []
    assert summary["decisions_redrawn"] == decisions, summary


def check_history(client: TestClient, db: Database, settings: Settings, user: SimUser) -> None:
    """Stats, a sample of traces, visits and the rebuild of a user without resets."""
    got = check_stats(client, user)
    assert got["cumulative_reward"][-1] == pytest.approx(got["total_reward"])
    check_stats(client, user, last=30)
    sample = {0, len(user.episodes) - 1, *range(3, len(user.episodes), 9)}
    for i in sorted(sample):
        check_trace(client, user, user.episodes[i])
    decisions = sum(len(ep.decisions) for ep in user.episodes)
    silent = sum(ep.silent_steps for ep in user.episodes)
    assert stored_steps(db, user.user_id) == (decisions, decisions, silent)
    assert model_visits(client, user.user_id) == decisions + silent
    r = client.get(f"/v1/users/{user.user_id}")
    assert r.status_code == 200
    assert r.json()["episodes"] == len(user.episodes)
    check_rebuild(settings, user.user_id, decisions)


# -- tests -------------------------------------------------------------------------------------
def test_simulated_users_through_the_api(
    robot: TestClient, db: Database, settings: Settings, engine_name: str
) -> None:
    """The issue's acceptance run: 3 users x 100 events, needs drifting at event 50."""
    began = time.perf_counter()
    users = make_users(np.random.default_rng(20261122), ["sim-a", "sim-b", "sim-c"], 100, 50)
    for e in range(100):  # users interleaved, as a fleet would report them
        for user in users:
            play_event(robot, user, e)
    played = time.perf_counter() - began
    for user in users:
        check_history(robot, db, settings, user)
    elapsed = time.perf_counter() - began
    print(
        f"\n{engine_name}: 3 users x 100 events played in {played:.1f} s, "
        f"checked in {elapsed - played:.1f} s"
    )  # shown, not asserted: machines are noisy

    # Seeded sanity of the learning itself: bounds, and orderings that hold robustly.
    for user in users:
        metrics = expected_stats(user.episodes)
        assert 0.0 <= metrics["success_rate"].expected <= 1.0
        assert 0.0 <= metrics["interaction_rate"].expected <= 1.0
    reward = np.asarray([[ep.expected_reward for ep in u.episodes] for u in users])
    success = np.asarray([[ep.success for ep in u.episodes] for u in users])
    # The learner improves on its start and recovers after the change. The same comparisons on
    # offline runs (hri, these profiles and streams) held for 200 of 200 seeds (the reward one
    # for 199). On this seed: successes 31 (events 81-100) vs 10 (51-60) vs 3 (1-10); reward
    # 200.5 vs 53.5.
    assert success[:, 80:100].sum() > success[:, 50:60].sum()
    assert success[:, 80:100].sum() > 1.5 * success[:, 0:10].sum()
    assert reward[:, 80:100].sum() > reward[:, 50:60].sum()


@pytest.mark.parametrize("algorithm", ["dts", "rmax", "qlearning"])
def test_other_learners_through_the_api(
    robot: TestClient, db: Database, settings: Settings, algorithm: str
) -> None:
    user_id = f"sim-{algorithm}"
    r = robot.put(f"/v1/users/{user_id}", json={"learner": {"algorithm": algorithm}})
    assert r.status_code == 201, r.text
    assert r.json()["learner"]["algorithm"] == algorithm
    (user,) = make_users(np.random.default_rng(7), [user_id], 60, 30)
    for e in range(60):
        play_event(robot, user, e)
    check_history(robot, db, settings, user)
    r = robot.get(f"/v1/users/{user_id}/model")
    assert r.json()["algorithm"] == algorithm


def test_feedback_and_resets_mid_history_rebuild_identically(
    robot: TestClient, admin: TestClient, db: Database, settings: Settings
) -> None:
    """Delayed and in-episode feedback, a reset between episodes and one inside an episode: the
    stats count every reward, and the model still rebuilds from the journal exactly."""
    (user,) = make_users(np.random.default_rng(11), ["sim-fb"], 60, 30)
    uid = user.user_id
    resets: list[tuple[int, int]] = []  # (event, tick) of each reset
    mid_episode_reset_due = False

    def feedback(seen: SeenEpisode, fid: str, word: str) -> None:
        url = f"/v1/episodes/{seen.episode_id}/feedback"
        body = {"feedback_id": fid, "feedback": word}
        out = post_json(robot, url, body)
        reward = REWARDS.positive if word == "positive" else REWARDS.negative
        assert out["reward"] == reward
        seen.expected_reward += reward
        seen.reward = out["episode"]["total_reward"]
        assert seen.reward == pytest.approx(seen.expected_reward)
        seen.feedback.append({"feedback_id": fid, "feedback": word, "reward": reward})
        again = robot.post(url, json=body)  # a robot's retry
        assert again.status_code == 200
        assert again.headers.get("Idempotent-Replay") == "true"
        assert again.json() == out

    def reset(event: int) -> None:
        r = admin.delete(f"/v1/users/{uid}/model")
        assert r.status_code == 204, r.text
        resets.append((event, next(TICK)))

    def during(seen: SeenEpisode, closed: bool) -> None:
        nonlocal mid_episode_reset_due
        if seen.event == 12:
            feedback(seen, f"fb-{seen.event}-during", "positive")
        if mid_episode_reset_due and not closed:
            reset(seen.event)  # between the episode's first outcome and its second
            mid_episode_reset_due = False

    for e in range(60):
        if e == 30:
            reset(e)
        if e == 45:
            mid_episode_reset_due = True
        play_event(robot, user, e, after_first_outcome=during)
        if e in (15, 25, 40, 55):
            feedback(user.episodes[e - 3], f"fb-{e}-late", "negative" if e % 2 else "positive")
        if e == 35:  # on an episode from before the reset
            feedback(user.episodes[5], "fb-35-before-reset", "positive")

    assert len(resets) == 2, resets
    assert not mid_episode_reset_due
    check_stats(robot, user)
    check_stats(robot, user, last=30)
    mid = resets[-1][0]
    for i in sorted({5, 9, 12, 22, 37, 52, 59, mid}):
        check_trace(robot, user, user.episodes[i])
    decisions = [d for ep in user.episodes for d in ep.decisions]
    silent = sum(len(d.chain) for d in decisions)
    assert stored_steps(db, uid) == (len(decisions), len(decisions), silent)
    # The model holds what was learned since the last reset: the outcomes reported after it, and
    # the silent steps of the decisions drawn after it (a decision drawn before it and answered
    # after it teaches the fresh model its outcome only).
    since = resets[-1][1]
    answered_after = sum(d.answered_tick > since for d in decisions)
    drawn_after = [d for d in decisions if d.drawn_tick > since]
    assert answered_after == len(drawn_after) + 1  # the reset fell inside an episode
    assert model_visits(robot, uid) == answered_after + sum(len(d.chain) for d in drawn_after)
    check_rebuild(settings, uid, len(drawn_after))


def test_feedback_on_an_episode_before_a_reset_leaves_the_fresh_model_alone(
    robot: TestClient, admin: TestClient, settings: Settings
) -> None:
    """DELETE /model forgets what was learned: feedback that arrives later for an episode from
    before the reset goes to history (the episode's trace and total), not into the new model,
    even when the new model has since executed the same action in the same context."""
    uid = "sim-reset-fb"

    def episode(i: int) -> tuple[str, str]:
        body = {
            "event_id": f"{uid}-{i}",
            "occurred_at": occurred_at("afternoon", "+08:00", i),
            "situation": "stretching",
            "initiator": "robot",
        }
        ep = post_json(robot, f"/v1/users/{uid}/episodes", body, 201)
        decision = ep["decision"]
        response = "rejected" if decision["action"]["kind"] == "initiate" else "none"
        out = post_json(
            robot,
            f"/v1/episodes/{ep['episode_id']}/outcomes",
            {"decision_id": decision["decision_id"], "response": response},
        )
        assert out["decision"] is None
        return ep["episode_id"], decision["action"]["kind"]

    before = [episode(i) for i in range(3)]
    r = admin.delete(f"/v1/users/{uid}/model")
    assert r.status_code == 204
    target_id, kind = before[0]
    seen_kinds: set[str] = set()
    for i in range(3, 40):  # until the fresh model has executed the target's action
        seen_kinds.add(episode(i)[1])
        if kind in seen_kinds:
            break
    assert kind in seen_kinds
    model = robot.get(f"/v1/users/{uid}/model").json()
    total = robot.get(f"/v1/episodes/{target_id}").json()["total_reward"]
    out = post_json(
        robot,
        f"/v1/episodes/{target_id}/feedback",
        {"feedback_id": "late-after-reset", "feedback": "positive"},
    )
    assert out["episode"]["total_reward"] == total + REWARDS.positive  # history has it
    after = robot.get(f"/v1/users/{uid}/model").json()
    assert after["version"] == model["version"], (
        "the fresh model took feedback on an episode it never saw"
    )
    assert after["contexts"] == model["contexts"]
    code, summary = rebuild(settings.database_url, uid, pooler=settings.database_pooler)
    assert code == 0, summary
