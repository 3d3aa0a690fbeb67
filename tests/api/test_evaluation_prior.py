"""The fleet's prior on or off as a candidate of an evaluation (``current:prior=on|off``, or a
learner with ``fleet_prior``), on both engines: where each person's candidate starts (the prior
the service gave them, fresh in its place, or today's prior of the others for those who started
fresh, never their own model in it, nobody's for those kept out), the evaluation through the
API with its keys and words, and the refusals (``current`` without a prior, HRI from a prior, a
shadow or a rollout of ``current``, ``fleet_prior`` on a rollout's candidate).

The settings lower the prior's thresholds (3 contributors with 3 episodes each) as
``tests/api/test_prior.py`` does, so that a small fleet has a prior."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.db.repositories import users as users_repo
from app.learning import make_learner
from app.learning.prior import population_prior
from app.services.evaluation import (
    CandidateSpec,
    _Priors,
    _read_person,
    _start,
    _wants_prior,
    parse_candidate,
)
from app.services.person_model import PersonModel
from app.settings import Settings
from tests.support.contract import assert_error
from tests.support.fixtures import WorkerDatabases
from tests.support.people import TEA, answer

EPISODES = 3  # per person: prior_min_episodes below
WAIT_S = 120.0  # a bound on how long the evaluation of this small fleet may take
URL = "/v1/admin/fleets/default/evaluations"


@pytest.fixture
def settings(database_url: str, worker_databases: WorkerDatabases) -> Settings:
    return Settings(
        database_url=database_url,
        database_pooler=worker_databases.pooler(database_url),
        seed=0,
        prior_min_contributors=3,  # type: ignore[call-arg]
        prior_min_episodes=EPISODES,
        _env_file=None,
    )


def _serve(client: TestClient, user_id: str, event_id: str) -> None:
    r = client.post(
        f"/v1/users/{user_id}/episodes",
        json={
            "event_id": event_id,
            "occurred_at": "2026-11-22T15:10:00+08:00",
            "situation": "stretching",
            "initiator": "robot",
        },
    )
    assert r.status_code == 201, r.text
    episode = r.json()
    decision = episode["decision"]
    while decision is not None:
        body = {"decision_id": decision["decision_id"], **answer(decision["action"], need=TEA)}
        r = client.post(f"/v1/episodes/{episode['episode_id']}/outcomes", json=body)
        assert r.status_code == 200, r.text
        decision = r.json()["decision"]


def _fleet(staff: TestClient) -> None:
    """ana, ben and cai start fresh (no prior yet); dan starts from their prior; eve keeps out
    of it; each served ``EPISODES`` times."""
    for name in ("ana", "ben", "cai", "dan"):
        assert staff.put(f"/v1/users/{name}", json={}).status_code == 201
        for n in range(EPISODES):
            _serve(staff, name, f"{name}-{n}")
    assert staff.put("/v1/users/eve", json={"fleet_prior": False}).status_code == 201
    for n in range(EPISODES):
        _serve(staff, "eve", f"eve-{n}")
    kinds = {
        n: staff.get(f"/v1/users/{n}/model").json()["started_from"]["kind"]
        for n in ("ana", "dan", "eve")
    }
    assert kinds == {"ana": "fresh", "dan": "fleet_prior", "eve": "fresh"}


def _tables(learner: Any) -> list[np.ndarray]:
    return [np.asarray(v) for k, v in sorted(vars(learner).items()) if isinstance(v, np.ndarray)]


def _same(a: Any, b: Any) -> bool:
    ta, tb = _tables(a), _tables(b)
    return len(ta) == len(tb) and all(
        x.shape == y.shape and np.allclose(x, y) for x, y in zip(ta, tb, strict=True)
    )


def test_where_each_persons_candidate_starts(app: FastAPI, staff: TestClient) -> None:
    _fleet(staff)
    on, off = parse_candidate("current:prior=on"), parse_candidate("current:prior=off")
    db, ctx = app.state.db, app.state.ctx
    with db.transaction(write=False) as session:
        user = {n: users_repo.get(session, "default", n) for n in ("ana", "dan", "eve")}
        assert all(u is not None for u in user.values())
        histories = {n: _read_person(session, ctx, u, None, None) for n, u in user.items() if u}
        priors = _Priors(ctx, "default")
        starts: dict[tuple[str, str], Any] = {}
        for name, history in histories.items():
            person = user[name]
            assert person is not None
            for spec in (on.for_person(person), off.for_person(person)):
                if _wants_prior(spec, history):
                    history.priors[spec.key] = priors.for_person(session, spec, history, person)
                starts[(name, "on" if spec.fleet_prior else "off")] = _start(spec, history)
        # The others' prior today, ana left out: what "on" starts ana from.
        others = []
        for name in ("ben", "cai", "dan"):
            found = users_repo.get(session, "default", name)
            assert found is not None
            others.append(PersonModel.open(session, ctx, found).learner)
        dan_base = PersonModel.open(session, ctx, user["dan"]).base_learner()  # type: ignore[arg-type]
    mission = histories["ana"].layouts[histories["ana"].base_layout].mission
    algorithm = user["ana"].algorithm  # type: ignore[union-attr]
    fresh = make_learner(algorithm, {}, mission)
    expected = population_prior(
        algorithm, fresh.params.to_dict(), mission, others, strength=ctx.settings.prior_strength
    )
    assert _same(starts[("ana", "on")], expected)
    assert _same(starts[("ana", "off")], fresh)  # as she started
    assert not _same(starts[("ana", "on")], fresh)
    assert _same(starts[("dan", "on")], dan_base)  # the prior the service gave him
    assert _same(starts[("dan", "off")], fresh)
    assert not _same(starts[("dan", "off")], dan_base)
    assert _same(starts[("eve", "on")], fresh)  # kept out of the prior: fresh either way
    assert _same(starts[("eve", "off")], fresh)


def test_an_evaluation_of_the_prior_on_and_off(app: FastAPI, staff: TestClient) -> None:
    _fleet(staff)
    body = {
        "request_id": "prior-or-not",
        "candidates": [
            {"algorithm": "current", "fleet_prior": True},
            {"algorithm": "current", "fleet_prior": False},
            {"algorithm": "dts", "fleet_prior": False},
        ],
    }
    r = staff.post(URL, json=body)
    assert r.status_code == 202, r.text
    location = r.headers["location"]
    asked = r.json()["candidates"]
    assert [c["key"] for c in asked] == ["current:prior=on", "current:prior=off", "dts:prior=off"]
    assert [c["fleet_prior"] for c in asked] == [True, False, False]
    assert asked[0]["label"] == "The current learners, with the fleet's prior"
    assert asked[2]["label"] == "DTS, without the fleet's prior"
    deadline = time.monotonic() + WAIT_S
    while (job := staff.get(location).json())["status"] in ("queued", "running"):
        assert time.monotonic() < deadline
        time.sleep(0.05)
    assert job["status"] == "done", job
    found = {c["key"]: c for c in job["result"]["candidates"]}
    assert [found[k]["fleet_prior"] for k in sorted(found)] == [False, True, False]
    assert set(found) == {"current:prior=on", "current:prior=off", "dts:prior=off"}
    assert all(c["estimate"]["n_episodes"] == 5 * EPISODES for c in found.values())
    again = staff.post(URL, json=body)  # the same request: the same job
    assert again.status_code == 200
    assert again.headers["idempotent-replay"] == "true"


@pytest.mark.parametrize(
    ("candidate", "words"),
    [
        ({"algorithm": "current"}, "current needs fleet_prior true or false"),
        ({"algorithm": "current", "params": {"tau": 0.1}}, "current takes no parameters"),
        ({"algorithm": "hri", "fleet_prior": True}, "HRI always starts fresh"),
        ({"algorithm": "dts", "fleet_prior": "sometimes"}, "fleet_prior"),
    ],
)
def test_a_prior_candidate_that_cannot_be(
    app: FastAPI, staff: TestClient, candidate: dict[str, Any], words: str
) -> None:
    assert staff.put("/v1/users/ana", json={}).status_code == 201
    r = staff.post(URL, json={"request_id": "bad", "candidates": [candidate]})
    assert_error(r, 422, "ValidationError")
    assert words in r.text


@pytest.mark.parametrize("what", ["shadow", "rollout"])
def test_a_shadow_or_rollout_tries_another_learner(
    app: FastAPI, staff: TestClient, what: str
) -> None:
    assert staff.put("/v1/users/ana", json={}).status_code == 201
    url = f"/v1/admin/fleets/default/{what}"
    r = staff.put(url, json={"candidate": {"algorithm": "current"}, "share": 0.5})
    assert_error(r, 422, "ValidationError")
    assert "a shadow or a rollout tries another learner" in r.text
    r = staff.put(url, json={"candidate": {"algorithm": "dts", "fleet_prior": False}, "share": 0.5})
    assert_error(r, 422, "ValidationError")


def test_the_candidates_text() -> None:
    assert parse_candidate("current:prior=off") == CandidateSpec("current", {}, False)
    assert parse_candidate("dts:prior=on,samples=8").key == "dts:prior=on,samples=8"
    assert parse_candidate("default:prior=off").label.endswith(", without the fleet's prior")
    for bad in ("current", "hri:prior=on", "dts:prior=maybe", "dts:prior=on,prior=off"):
        with pytest.raises(ValueError, match="candidate"):
            parse_candidate(bad)
