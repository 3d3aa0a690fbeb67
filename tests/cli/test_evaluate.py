"""``attune evaluate`` on both engines: a fleet filled through the real API, then candidates
estimated from its stored logs.

The fleet: six people created with an HRI learner, six episodes each, played by simulated
people (``tests/support/people.py``), some begun by the person (the robot's forced steps),
negative feedback after every other episode, staff corrections (one lifted again), a change of
the fleet's mission half-way (every model moves), and one person's model reset (the history
before it is not evaluated; the reset keeps their correction, so the model's base is stored).

HRI draws no plan: its distributions are a function of what it learned, so the fleet's own
learner replayed through the stored history gives each logged action the very probability it
was drawn with. Every importance weight is then 1: the unweighted estimators give exactly the
mean total reward of the episodes counted, and the effective sample size is their number.
"""

from __future__ import annotations

import copy
import json
import random
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select

from app.db.models import AuditEntry, Episode, JournalEntry, User
from app.db.session import Database
from app.learning.offpolicy import DEFAULT_ESTIMATOR, ESTIMATORS
from app.services.evaluation import CandidateSpec, parse_candidate
from tests.support import people
from tests.support.episodes import play
from tests.support.fixtures import MakeKey
from tests.support.office import MISSION

from .conftest import Attune

PEOPLE = 6
EPISODES = 6  # each, on days 2 to 7 of November 2026
NEEDS = (("ProvideDrink", "tea"), ("BriefInformation", "news"), ("ProvideDrink", "coffee"))
MISSION_CHANGE_AFTER = 2  # the fleet's mission changes after everyone's third episode
RESET = ("person-0", 3)  # whose model is reset, after which of their episodes
BEFORE_THE_BASE = RESET[1] + 1  # their episodes left out: those before the reset
COUNTED = PEOPLE * EPISODES - BEFORE_THE_BASE


def _client(app: FastAPI, key: str) -> TestClient:
    return TestClient(
        app,
        headers={"Authorization": f"Bearer {key}"},
        raise_server_exceptions=False,
        client=("127.0.0.1", 50000),
    )


def _correct(staff: TestClient, user: str) -> None:
    r = staff.post(
        f"/v1/users/{user}/corrections",
        json={
            "correction_id": "c1",
            "time_slot": "afternoon",
            "situation": "stretching",
            "kind": "prefers",
            "service": "ProvideDrink",
            "detail": "tea",
        },
    )
    assert r.status_code == 201, r.text


def _fill(app: FastAPI, make_key: MakeKey) -> None:
    """The fleet of the module's docstring, in fleet ``default``."""
    changed = copy.deepcopy(MISSION.to_dict())
    changed["services"][0]["details"].append("cocoa")
    with (
        _client(app, make_key("robot")) as robot,
        _client(app, make_key("staff")) as staff,
    ):
        users = [f"person-{p}" for p in range(PEOPLE)]
        answers = []
        for p, user in enumerate(users):
            r = robot.put(f"/v1/users/{user}", json={"learner": {"algorithm": "hri"}})
            assert r.status_code == 201, r.text
            need = NEEDS[p % len(NEEDS)]
            rng = random.Random(p)
            answers.append(
                (need, people.person(need=need, rng=rng, yes=0.8, asks=0.6, precise=0.5))
            )
        for e in range(EPISODES):
            for p, user in enumerate(users):
                need, person = answers[p]
                human = e % 3 == 2
                played = play(
                    robot,
                    user,
                    f"{user}-event-{e}",
                    person,
                    occurred_at=f"2026-11-0{2 + e}T15:10:00+08:00",
                    initiator="human" if human else "robot",
                    request={"service": need[0], "detail": None} if human else None,
                )
                if e % 2 == 1:
                    r = robot.post(
                        f"/v1/episodes/{played.episode_id}/feedback",
                        json={"feedback_id": f"fb-{e}", "feedback": "negative"},
                    )
                    assert r.status_code == 200, r.text
                if e == 1 and p < 2:
                    _correct(staff, user)
                if (user, e) == RESET:
                    r = staff.delete(f"/v1/users/{user}/model")
                    assert r.status_code == 204, r.text
                if (user, e) == (RESET[0], RESET[1] + 1):
                    r = staff.delete(f"/v1/users/{user}/corrections/c1")
                    assert r.status_code == 204, r.text
            if e == MISSION_CHANGE_AFTER:
                r = staff.put(
                    "/v1/admin/fleets/default/mission",
                    json={"change_id": "cocoa", "mission": changed},
                )
                assert r.status_code == 200, r.text


def _counted_returns(db: Database) -> list[float]:
    """The total rewards of the episodes an evaluation counts: all closed ones but those of the
    reset person before their reset."""
    with db.transaction(write=False) as session:
        rows = session.execute(
            select(User.user_id, Episode.seq, Episode.total_reward)
            .join(User, User.id == Episode.user_pk)
            .where(Episode.status == "closed")
        ).all()
    return [r for user, seq, r in rows if not (user == RESET[0] and seq <= BEFORE_THE_BASE)]


def _evaluate(attune: Attune, *args: str) -> dict[str, Any]:
    done = attune("evaluate", "--fleet", "default", "--json", "--no-progress", *args)
    assert done.exit_code == 0, done.output
    assert done.stderr == ""
    found: dict[str, Any] = json.loads(done.stdout)
    return found


def test_the_fleets_own_learner_earns_what_the_logs_show(
    attune: Attune, app: FastAPI, db: Database, make_key: MakeKey
) -> None:
    _fill(app, make_key)
    with db.transaction(write=False) as session:
        kinds = set(session.scalars(select(JournalEntry.kind).distinct()))
    assert kinds == {"transition", "feedback", "correction", "lift", "mission", "reset"}
    returns = _counted_returns(db)
    assert len(returns) == COUNTED
    mean = sum(returns) / len(returns)
    for estimator in ("pdis", "wpdis"):
        found = _evaluate(attune, "--candidate", "hri", "--estimator", estimator)
        assert found["episodes"] == COUNTED
        assert found["skipped"] == {"before the model's base": BEFORE_THE_BASE}
        assert found["logged"]["value"] == pytest.approx(mean, abs=1e-9)
        assert found["logged"]["ess"] == COUNTED
        [hri] = found["candidates"]
        assert hri["entries_refused"] == 0
        e = hri["estimate"]
        assert e["enough"], e["reason"]
        assert e["value"] == pytest.approx(mean, abs=1e-9)
        assert e["ess"] == pytest.approx(COUNTED, rel=1e-9)
        assert e["weight_mean"] == pytest.approx(1.0, abs=1e-9)
        assert e["clipped_share"] == 0.0
        assert e["unsupported_max"] == pytest.approx(0.0, abs=1e-12)
        assert hri["difference"]["value"] == pytest.approx(0.0, abs=1e-9)
        assert hri["difference"]["low"] == pytest.approx(0.0, abs=1e-9)
        assert hri["difference"]["high"] == pytest.approx(0.0, abs=1e-9)
        assert hri["verdict"].startswith("HRI would earn about the same as what the robots do now")
    # The doubly robust estimate adds the candidate's model as a control variate: with every
    # weight 1 its terms cancel in expectation, not episode by episode.
    for estimator in ("dr", "wdr"):
        [dr] = _evaluate(attune, "--candidate", "hri", "--estimator", estimator)["candidates"]
        assert dr["estimate"]["estimator"] == estimator
        assert dr["estimate"]["ess"] == pytest.approx(COUNTED, rel=1e-9)
        low, high = dr["estimate"]["interval"]["low"], dr["estimate"]["interval"]["high"]
        assert low < mean < high


def test_a_candidate_far_from_the_logger_gets_no_narrow_number(
    attune: Attune, app: FastAPI, make_key: MakeKey
) -> None:
    """DTS-routine trusts routines and R-MAX plans on an optimistic model: neither does what the
    HRI robots did as often as they did. DTS-routine's weights rest on a handful of episodes: no
    number, "not enough evidence" with the figures. R-MAX, by each estimator, gets either no
    verdict (with dr, an interval wider than anything the robots earned) or an interval wider
    than the robots' own, and "about the same": never a narrow verdict. A candidate near the
    logger gets a number, its interval, and words."""
    _fill(app, make_key)
    found = _evaluate(
        attune, "--candidate", "dts-routine", "--candidate", "hri:tau=0.005", "--estimator", "dr"
    )
    far, near = found["candidates"]
    assert not far["enough"]
    assert far["difference"] is None
    assert far["estimate"]["value"] is None
    assert far["estimate"]["ess"] < 10
    assert far["reason"].startswith(f"not enough evidence: {COUNTED} episodes, effective size ")
    assert far["verdict"] == far["reason"]
    assert near["enough"], near["reason"]
    assert near["estimate"]["interval"]["low"] <= near["estimate"]["value"]
    assert near["estimate"]["value"] <= near["estimate"]["interval"]["high"]
    d = near["difference"]
    assert d["low"] <= d["value"] <= d["high"]
    assert d["method"] == "bootstrap"
    assert near["verdict"].startswith("HRI τ=0.005 would ")
    assert " per encounter, between " in near["verdict"]
    for estimator in ESTIMATORS:
        run = _evaluate(attune, "--candidate", "rmax", "--estimator", estimator)
        [rmax] = run["candidates"]
        if not rmax["enough"]:
            assert rmax["difference"] is None
            assert rmax["verdict"] == rmax["reason"]
            assert rmax["reason"].startswith("not enough evidence: ")
            continue
        now, its = run["logged"]["interval"], rmax["estimate"]["interval"]
        assert its["high"] - its["low"] > now["high"] - now["low"]
        assert rmax["difference"]["low"] < 0.0 < rmax["difference"]["high"]
        assert rmax["verdict"].startswith("R-MAX would earn about the same")


def test_since_beyond_every_episode_is_not_enough_evidence(
    attune: Attune, app: FastAPI, make_key: MakeKey
) -> None:
    _fill(app, make_key)
    found = _evaluate(attune, "--candidate", "dts", "--since", "2026-12-01")
    assert found["episodes"] == 0
    assert found["skipped"] == {"outside the window": PEOPLE * EPISODES}
    assert found["persons"] == []
    assert not found["logged"]["enough"]
    [dts] = found["candidates"]
    assert dts["verdict"].startswith("not enough evidence: 0 episodes")
    table = attune("evaluate", "--fleet", "default", "--candidate", "dts", "--since", "2026-12-01")
    assert table.exit_code == 0, table.output
    assert "not enough evidence: 0 episodes" in table.stdout
    # A window that holds some: the candidates still learn from what came before it.
    window = _evaluate(
        attune, "--candidate", "hri", "--estimator", "wpdis", "--since", "2026-11-05T00:00+08:00"
    )
    assert window["episodes"] == PEOPLE * (EPISODES - 3) - (BEFORE_THE_BASE - 3)
    assert window["candidates"][0]["estimate"]["weight_mean"] == pytest.approx(1.0, abs=1e-9)
    until = _evaluate(attune, "--candidate", "hri", "--until", "2026-11-05")
    assert until["episodes"] == PEOPLE * 3 - 3


def test_json_has_every_candidate_and_every_person(
    attune: Attune, app: FastAPI, make_key: MakeKey
) -> None:
    _fill(app, make_key)
    done = attune(
        "evaluate",
        "--fleet",
        "default",
        "--candidate",
        "dts",
        "--candidate",
        "hri:tau=0.005",
        "--json",
        "--per-person",
        "--no-progress",
    )
    assert done.exit_code == 0, done.output
    found = json.loads(done.stdout)
    assert found["fleet"] == "default"
    assert found["estimator"] == DEFAULT_ESTIMATOR
    assert found["people"] == found["people_counted"] == PEOPLE
    assert found["learners"] == {"hri": PEOPLE}
    assert [c["key"] for c in found["candidates"]] == ["dts", "hri:tau=0.005"]
    assert [c["label"] for c in found["candidates"]] == ["DTS", "HRI τ=0.005"]
    for c in found["candidates"]:
        assert set(c) >= {"estimate", "difference", "verdict", "enough", "reason", "params"}
        assert c["estimate"]["n_episodes"] == COUNTED
        assert c["estimate"]["n_clusters"] == PEOPLE
    rows = found["persons"]
    assert sorted(p["user_id"] for p in rows) == [f"person-{p}" for p in range(PEOPLE)]
    assert sum(p["episodes"] for p in rows) == COUNTED
    for row in rows:
        assert set(row["candidates"]) == {"dts", "hri:tau=0.005"}
        assert row["logged"]["n_episodes"] == row["episodes"]
    # The table: one row per candidate beside the robots' own, and one per person.
    table = attune("evaluate", "--fleet", "default", "--candidate", "hri:tau=0.005", "--per-person")
    assert table.exit_code == 0, table.output
    assert "what the robots do now" in table.stdout
    assert "HRI τ=0.005" in table.stdout
    assert all(f"person-{p}" in table.stdout for p in range(PEOPLE))
    assert "people of default" not in table.stdout  # the progress bar: on stderr
    # Each run is in the audit log, as the operator's.
    with app.state.db.transaction(write=False) as session:
        runs = session.execute(
            select(AuditEntry.actor_key_id, AuditEntry.target, AuditEntry.detail).where(
                AuditEntry.action == "evaluation.run"
            )
        ).all()
    assert [(who, target) for who, target, _ in runs] == [("cli", "default")] * 2
    assert runs[0][2]["candidates"] == ["dts", "hri:tau=0.005"]


def test_bad_candidates_and_unknown_fleets_are_refused(
    attune: Attune, app: FastAPI, make_key: MakeKey
) -> None:
    _fill(app, make_key)
    for text, said in (
        ("sarsa", "the algorithm must be one of dts, dts-adapt, dts-routine, hri, qlearning"),
        ("hri:tuo=0.1", "tuo is not a parameter of hri"),
        ("hri:tau=warm", "tau must be a number, got 'warm'"),
        ("hri:tau=500", "tau must be in [0, 100], got 500.0"),
        ("hri:tau", "'tau' is not NAME=VALUE"),
    ):
        done = attune("evaluate", "--fleet", "default", "--candidate", text, "--no-progress")
        assert done.exit_code == 2, (text, done.output)
        assert said in " ".join(done.stderr.split()), done.stderr
        assert done.stdout == ""
    missing = attune("evaluate", "--fleet", "default", "--no-progress")
    assert missing.exit_code == 2
    assert "give at least one" in " ".join(missing.stderr.split())
    unknown = attune("evaluate", "--fleet", "nowhere", "--candidate", "dts", "--no-progress")
    assert unknown.exit_code == 2, unknown.output
    assert unknown.stderr.strip() == "No fleet 'nowhere': no person of this database is in it."
    assert unknown.stdout == ""
    for option, value in (("--since", "yesterday"), ("--estimator", "ips")):
        bad = attune("evaluate", "--fleet", "default", "--candidate", "dts", option, value)
        assert bad.exit_code == 2, bad.output


def test_a_rerun_gives_the_same_numbers(attune: Attune, app: FastAPI, make_key: MakeKey) -> None:
    _fill(app, make_key)
    args = ("--candidate", "dts", "--candidate", "dts-routine:samples=32", "--per-person")
    first = _evaluate(attune, *args)
    assert _evaluate(attune, *args) == first


# -- the candidates' text (no database) ----------------------------------------------------------
@pytest.mark.parametrize(
    ("text", "algorithm", "params", "key", "label"),
    [
        ("dts", "dts", {}, "dts", "DTS"),
        ("hri:tau=0.005", "hri", {"tau": 0.005}, "hri:tau=0.005", "HRI τ=0.005"),
        ("hri:tau=1", "hri", {"tau": 1.0}, "hri:tau=1", "HRI τ=1"),
        (
            "dts-routine:samples=32,ask_unknown=false",
            "dts-routine",
            {"samples": 32, "ask_unknown": False},
            "dts-routine:ask_unknown=false,samples=32",
            "DTS-routine ask_unknown=false samples=32",
        ),
        (" rmax : ", None, None, None, None),
        # "default": the learner a person gets when nobody chooses one.
        ("default", "dts-routine", {}, "dts-routine", "DTS-routine"),
        ("default:samples=32", "dts-routine", {"samples": 32}, "dts-routine:samples=32", None),
    ],
)
def test_candidate_text(
    text: str,
    algorithm: str | None,
    params: dict[str, Any] | None,
    key: str | None,
    label: str | None,
) -> None:
    if algorithm is None:
        with pytest.raises(ValueError, match="no parameters after ':'"):
            parse_candidate(text)
        return
    spec = parse_candidate(text)
    assert spec == CandidateSpec(algorithm, params or {})
    assert spec.key == key
    if label is not None:
        assert spec.label == label
    assert parse_candidate(spec.key) == spec
