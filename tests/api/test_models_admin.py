"""Models, stats and model administration: what the learner believes, the paper's metrics,
reset, export and import."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.support.contract import assert_error
from tests.support.episodes import report, start

TEA = {"service": "ProvideDrink", "detail": "tea"}
ACTION_KEYS = {"action", "q", "visits", "kept_visits", "since_last", "measure", "p"}


def model(client: TestClient, user_id: str, **params: str) -> dict[str, Any]:
    r = client.get(f"/v1/users/{user_id}/model", params=params)
    assert r.status_code == 200, r.text
    body: dict[str, Any] = r.json()
    return body


def actions(view: dict[str, Any]) -> list[dict[str, Any]]:
    return [a for c in view["contexts"] for s in c["states"] for a in s["actions"]]


def root(
    view: dict[str, Any], slot: str = "afternoon", situation: str = "stretching"
) -> dict[str, dict[str, Any]]:
    """The OBSERVE actions of one context, by kind."""
    [ctx] = [c for c in view["contexts"] if (c["time_slot"], c["situation"]) == (slot, situation)]
    [observe] = [s for s in ctx["states"] if s["state"] == "OBSERVE"]
    return {a["action"]["kind"]: a for a in observe["actions"]}


def served(
    client: TestClient, user_id: str, event_id: str, response: str = "accepted"
) -> dict[str, Any]:
    """A closed human-initiated episode (tea performed, then ``response``)."""
    ep = start(client, user_id, event_id, initiator="human", request=TEA)
    return report(client, ep["episode_id"], ep["decision"]["decision_id"], response)


def finish(client: TestClient, ep: dict[str, Any]) -> tuple[float, int, bool, str]:
    """Play an episode to its end, positively; (total reward, queries, initiated, kind)."""
    decision = ep["decision"]
    first_kind = decision["action"]["kind"]
    queries = 0
    total = ep["total_reward"]
    while decision is not None:
        kind = decision["action"]["kind"]
        queries += kind.startswith("query_")
        extra: dict[str, Any] = {}
        if kind == "initiate":
            response = "rejected"
        elif kind == "pass":
            response = "none"
        elif kind == "query_type":
            response, extra = "answered", {"service": "ProvideDrink"}
        elif kind == "query_detail":
            response, extra = "answered", {"detail": "tea"}
        else:
            response = "accepted"
        out = report(client, ep["episode_id"], decision["decision_id"], response, **extra)
        total = out["episode"]["total_reward"]
        decision = out["decision"]
    return total, queries, ep["state"] == "OBSERVE" and first_kind == "initiate", first_kind


class TestGetModel:
    def test_shape(self, robot: TestClient) -> None:
        robot.put("/v1/users/lin")
        view = model(robot, "lin")
        assert set(view) >= {"user_id", "algorithm", "params", "version", "episodes", "contexts"}
        assert (view["user_id"], view["algorithm"], view["episodes"]) == ("lin", "dts-routine", 0)
        assert view["started_from"] == {"kind": "fresh", "contributors": None}
        assert view["params"]["forgetting"] == pytest.approx(0.95)
        assert isinstance(view["version"], int)
        assert len(view["contexts"]) == 16
        pairs = {(c["time_slot"], c["situation"]) for c in view["contexts"]}
        assert ("evening", "busy") in pairs
        assert ("morning", "arriving") in pairs
        for ctx in view["contexts"]:
            states = [s["state"] for s in ctx["states"]]
            assert states[0] == "OBSERVE"
            assert {"ENGAGED", "REQUEST", "TYPE_KNOWN", "DETAIL_KNOWN"} <= set(states)
            for state in ctx["states"]:
                assert state["actions"]
                assert sum(a["p"] for a in state["actions"]) == pytest.approx(1.0)
                for a in state["actions"]:
                    assert set(a) >= ACTION_KEYS
                    assert a["visits"] == 0
                    assert isinstance(a["q"], float)
                    assert a["measure"] is None  # HRI's temporal measure only
                    assert isinstance(a["kept_visits"], float)
        kinds = root(view)
        assert set(kinds) == {"initiate", "pass"}

    def test_filters(self, robot: TestClient) -> None:
        robot.put("/v1/users/lin")
        one = model(robot, "lin", time_slot="afternoon", situation="stretching")
        assert [(c["time_slot"], c["situation"]) for c in one["contexts"]] == [
            ("afternoon", "stretching")
        ]
        slot = model(robot, "lin", time_slot="morning")
        assert len(slot["contexts"]) == 4
        assert {c["time_slot"] for c in slot["contexts"]} == {"morning"}
        situation = model(robot, "lin", situation="busy")
        assert {c["time_slot"] for c in situation["contexts"]} == {
            "morning",
            "noon",
            "afternoon",
            "evening",
        }
        assert {c["situation"] for c in situation["contexts"]} == {"busy"}
        full = model(robot, "lin")
        assert one["contexts"][0] in full["contexts"]

    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        ("query", "names"),
        [
            ({"time_slot": "dawn"}, ["morning", "noon", "afternoon", "evening"]),
            ({"situation": "sleeping"}, ["arriving", "working", "stretching", "busy"]),
            ({"time_slot": "Morning"}, ["morning"]),
        ],
    )
    def test_bad_filters_are_422(
        self, robot: TestClient, query: dict[str, str], names: list[str]
    ) -> None:
        robot.put("/v1/users/lin")
        body = assert_error(robot.get("/v1/users/lin/model", params=query), 422, "ValidationError")
        for name in names:
            assert name in body["detail"]

    def test_unknown_and_foreign_users_are_404(
        self, robot: TestClient, other_robot: TestClient
    ) -> None:
        assert_error(robot.get("/v1/users/nobody/model"), 404, "NotFound")
        robot.put("/v1/users/lin")
        assert_error(other_robot.get("/v1/users/lin/model"), 404, "NotFound")
        assert_error(other_robot.get("/v1/users/lin/stats"), 404, "NotFound")

    def test_version_goes_up_by_one_per_outcome_and_not_on_reads(self, robot: TestClient) -> None:
        ep = start(robot, "lin", "e1", initiator="human", request={"service": "ProvideDrink"})
        v0 = model(robot, "lin")["version"]
        for _ in range(3):
            robot.get("/v1/users/lin/model")
            robot.get("/v1/users/lin/stats")
            robot.get(f"/v1/episodes/{ep['episode_id']}")
        assert model(robot, "lin")["version"] == v0
        decision = ep["decision"]
        expected = v0
        while decision is not None:
            kind = decision["action"]["kind"]
            extra = {"detail": "tea"} if kind == "query_detail" else {}
            out = report(
                robot,
                ep["episode_id"],
                decision["decision_id"],
                "answered" if kind == "query_detail" else "accepted",
                **extra,
            )
            expected += 1
            assert model(robot, "lin")["version"] == expected
            decision = out["decision"]
        assert model(robot, "lin")["version"] == expected

    def test_a_refused_outcome_does_not_change_the_version(self, robot: TestClient) -> None:
        ep = start(robot, "lin", "e1", initiator="human", request=TEA)
        before = model(robot, "lin")
        r = robot.post(
            f"/v1/episodes/{ep['episode_id']}/outcomes",
            json={"decision_id": ep["decision"]["decision_id"], "response": "none"},
        )
        assert r.status_code == 422
        assert model(robot, "lin") == before

    def test_a_replayed_outcome_does_not_change_the_version(self, robot: TestClient) -> None:
        ep = start(robot, "lin", "e1", initiator="human", request=TEA)
        body = {"decision_id": ep["decision"]["decision_id"], "response": "accepted"}
        robot.post(f"/v1/episodes/{ep['episode_id']}/outcomes", json=body)
        before = model(robot, "lin")
        robot.post(f"/v1/episodes/{ep['episode_id']}/outcomes", json=body)
        assert model(robot, "lin") == before

    def test_learning_shows_in_visits(self, robot: TestClient) -> None:
        for i in range(3):
            served(robot, "lin", f"e{i}")
        view = model(robot, "lin", time_slot="afternoon", situation="stretching")
        assert view["episodes"] == 3
        kinds = root(view)
        assert kinds["pass"]["visits"] == 3
        assert kinds["initiate"]["visits"] == 0
        assert kinds["pass"]["q"] > 0
        untouched = model(robot, "lin", time_slot="morning")
        assert all(a["visits"] == 0 for a in actions(untouched))

    def test_qlearning_has_no_measure_or_kept_visits(self, robot: TestClient) -> None:
        robot.put("/v1/users/q", json={"learner": {"algorithm": "qlearning"}})
        served(robot, "q", "e1")
        view = model(robot, "q")
        assert view["algorithm"] == "qlearning"
        for a in actions(view):
            assert a["measure"] is None
            assert a["kept_visits"] is None
            assert isinstance(a["q"], float)
            assert isinstance(a["visits"], int)
        assert root(view)["pass"]["visits"] == 1


class TestStats:
    def test_a_user_without_episodes(self, robot: TestClient) -> None:
        robot.put("/v1/users/lin")
        r = robot.get("/v1/users/lin/stats")
        assert r.status_code == 200
        stats = r.json()
        assert stats["episodes"] == 0
        assert stats["missions"] == 0
        assert stats["total_reward"] == 0.0
        assert stats["cumulative_reward"] == [0.0]
        assert stats["success_rate"] is None
        assert stats["queries_per_mission"] is None

    def test_definitions(self, robot: TestClient) -> None:
        rewards: list[float] = []
        initiated = missions = successes = queries = 0
        # 1: the person asks for tea and takes it: I1, a mission and a success, no query
        rewards.append(served(robot, "lin", "e1")["episode"]["total_reward"])
        missions += 1
        successes += 1
        # 2-5: the robot decides: initiate (rejected: I3) or pass (no interaction)
        for i in range(2, 6):
            ep = start(robot, "lin", f"e{i}")
            total, q, init, _ = finish(robot, ep)
            rewards.append(total)
            initiated += init
            missions += init
            queries += q
        # 6: the person asks without saying what: queries may follow, then tea is served
        ep = start(robot, "lin", "e6", initiator="human")
        total, q, _, _ = finish(robot, ep)
        rewards.append(total)
        missions += 1
        successes += 1
        queries += q
        # 7: the person asks for tea and refuses it: a mission without success
        rewards.append(served(robot, "lin", "e7", "rejected")["episode"]["total_reward"])
        missions += 1

        stats = robot.get("/v1/users/lin/stats").json()
        assert stats["episodes"] == 7
        assert stats["missions"] == missions
        assert stats["interaction_rate"] == pytest.approx(initiated / 7)
        assert stats["success_rate"] == pytest.approx(successes / missions)
        assert stats["queries_per_mission"] == pytest.approx(queries / missions)
        assert stats["total_reward"] == pytest.approx(sum(rewards))
        expected = [0.0]
        for r in rewards:
            expected.append(expected[-1] + r)
        assert stats["cumulative_reward"] == pytest.approx(expected)
        assert rewards[0] == 7.0
        assert rewards[-1] == -1.0

        last = robot.get("/v1/users/lin/stats", params={"last": 2}).json()
        assert last["episodes"] == 2
        assert last["missions"] == 2
        assert last["success_rate"] == pytest.approx(0.5)
        assert last["total_reward"] == pytest.approx(rewards[-2] + rewards[-1])
        assert last["cumulative_reward"] == pytest.approx(
            [0.0, rewards[-2], rewards[-2] + rewards[-1]]
        )
        everything = robot.get("/v1/users/lin/stats", params={"last": 100}).json()
        assert everything == stats

    def test_feedback_counts_in_total_reward(self, robot: TestClient) -> None:
        out = served(robot, "lin", "e1")
        robot.post(
            f"/v1/episodes/{out['episode']['episode_id']}/feedback",
            json={"feedback_id": "f1", "feedback": "negative"},
        )
        stats = robot.get("/v1/users/lin/stats").json()
        assert stats["total_reward"] == 5.0
        assert stats["cumulative_reward"] == [0.0, 5.0]


class TestResetModel:
    def test_admin_resets_and_history_stays(self, robot: TestClient, admin: TestClient) -> None:
        out = served(robot, "lin", "e1")
        served(robot, "lin", "e2")
        before = model(robot, "lin")
        stats = robot.get("/v1/users/lin/stats").json()
        trace = robot.get(f"/v1/episodes/{out['episode']['episode_id']}").json()
        r = admin.delete("/v1/users/lin/model")
        assert r.status_code == 204
        assert r.content == b""
        after = model(robot, "lin")
        assert all(a["visits"] == 0 for a in actions(after))
        assert any(a["visits"] > 0 for a in actions(before))
        assert after["version"] == before["version"] + 1
        assert after["algorithm"] == before["algorithm"]
        assert after["params"] == before["params"]
        assert robot.get("/v1/users/lin").json()["episodes"] == 2
        assert robot.get("/v1/users/lin/stats").json() == stats
        assert robot.get(f"/v1/episodes/{out['episode']['episode_id']}").json() == trace
        # and the user goes on learning from there
        served(robot, "lin", "e3")
        assert root(model(robot, "lin"))["pass"]["visits"] == 1

    @pytest.mark.one_engine
    def test_robot_is_403_and_nothing_changes(self, robot: TestClient) -> None:
        served(robot, "lin", "e1")
        before = model(robot, "lin")
        assert_error(robot.delete("/v1/users/lin/model"), 403, "Forbidden")
        assert model(robot, "lin") == before

    def test_unknown_user_is_404(self, admin: TestClient) -> None:
        assert_error(admin.delete("/v1/users/nobody/model"), 404, "NotFound")


class TestExportImport:
    def test_export_is_self_describing(self, robot: TestClient, admin: TestClient) -> None:
        served(robot, "lin", "e1")
        r = admin.get("/v1/users/lin/model/export")
        assert r.status_code == 200
        doc = r.json()
        assert set(doc) >= {"format", "format_version", "algorithm", "params", "arrays", "mission"}
        assert doc["algorithm"] == "dts-routine"
        assert doc["params"]["forgetting"] == pytest.approx(0.95)
        assert doc["mission"]["name"] == "office"

    def test_import_on_another_user_gives_the_same_model_view(
        self, robot: TestClient, admin: TestClient
    ) -> None:
        for i in range(3):
            served(robot, "lin", f"e{i}")
        robot.put("/v1/users/twin", json={"learner": {"algorithm": "rmax"}})
        doc = admin.get("/v1/users/lin/model/export").json()
        r = admin.put("/v1/users/twin/model", json=doc)
        assert r.status_code == 200, r.text
        source, copy = model(robot, "lin"), model(robot, "twin")
        assert r.json() == copy
        assert copy["user_id"] == "twin"
        assert (copy["algorithm"], copy["params"]) == (source["algorithm"], source["params"])
        assert copy["contexts"] == source["contexts"]
        assert robot.get("/v1/users/twin").json()["learner"] == {
            "algorithm": "dts-routine",
            "params": source["params"],
        }

    def test_round_trip_after_a_reset(self, robot: TestClient, admin: TestClient) -> None:
        for i in range(2):
            served(robot, "lin", f"e{i}")
        before = model(robot, "lin")
        doc = admin.get("/v1/users/lin/model/export").json()
        admin.delete("/v1/users/lin/model")
        r = admin.put("/v1/users/lin/model", json=doc)
        assert r.status_code == 200, r.text
        after = model(robot, "lin")
        assert after["contexts"] == before["contexts"]
        assert after["version"] > before["version"]
        # the imported model goes on learning
        served(robot, "lin", "e9")
        assert root(model(robot, "lin"))["pass"]["visits"] == 3

    def test_qlearning_round_trip(self, robot: TestClient, admin: TestClient) -> None:
        robot.put("/v1/users/q", json={"learner": {"algorithm": "qlearning"}})
        served(robot, "q", "e1")
        doc = admin.get("/v1/users/q/model/export").json()
        robot.put("/v1/users/q2")
        assert admin.put("/v1/users/q2/model", json=doc).status_code == 200
        assert model(robot, "q2")["contexts"] == model(robot, "q")["contexts"]
        assert model(robot, "q2")["algorithm"] == "qlearning"

    @pytest.mark.parametrize(
        "change",
        [
            {"format": "something-else"},
            {"format_version": 999},
            {"mission": {"name": "office", "fingerprint": "sha256:" + "0" * 64}},
            {"mission": {"name": "warehouse", "fingerprint": "sha256:" + "0" * 64}},
            {"algorithm": "sarsa"},
            {"params": {"tau": -1}},
            {"arrays": {}},
            {"arrays": "garbage"},
        ],
    )
    def test_wrong_documents_are_422_and_change_nothing(
        self, robot: TestClient, admin: TestClient, change: dict[str, Any]
    ) -> None:
        served(robot, "lin", "e1")
        doc = admin.get("/v1/users/lin/model/export").json()
        before = (model(robot, "lin"), robot.get("/v1/users/lin").json())
        assert_error(
            admin.put("/v1/users/lin/model", json={**doc, **change}), 422, "ValidationError"
        )
        assert (model(robot, "lin"), robot.get("/v1/users/lin").json()) == before

    @pytest.mark.parametrize("doc", [{}, {"hello": "world"}, [], "x", 3, None])
    def test_garbage_is_422(self, robot: TestClient, admin: TestClient, doc: Any) -> None:
        served(robot, "lin", "e1")
        before = model(robot, "lin")
        r = admin.put("/v1/users/lin/model", json=doc)
        assert_error(r, 422, "ValidationError")
        assert model(robot, "lin") == before

    def test_a_corrupted_array_is_422(self, robot: TestClient, admin: TestClient) -> None:
        served(robot, "lin", "e1")
        doc = admin.get("/v1/users/lin/model/export").json()
        name = sorted(doc["arrays"])[0]
        bad = {**doc, "arrays": {**doc["arrays"], name: {**doc["arrays"][name], "data": "AAAA"}}}
        before = model(robot, "lin")
        assert_error(admin.put("/v1/users/lin/model", json=bad), 422, "ValidationError")
        assert model(robot, "lin") == before

    def test_robot_is_403_on_export_and_import(self, robot: TestClient, admin: TestClient) -> None:
        served(robot, "lin", "e1")
        doc = admin.get("/v1/users/lin/model/export").json()
        before = model(robot, "lin")
        assert_error(robot.get("/v1/users/lin/model/export"), 403, "Forbidden")
        assert_error(robot.put("/v1/users/lin/model", json=doc), 403, "Forbidden")
        assert model(robot, "lin") == before

    def test_unknown_user_is_404(self, admin: TestClient, robot: TestClient) -> None:
        served(robot, "lin", "e1")
        doc = admin.get("/v1/users/lin/model/export").json()
        assert_error(admin.get("/v1/users/nobody/model/export"), 404, "NotFound")
        assert_error(admin.put("/v1/users/nobody/model", json=doc), 404, "NotFound")
        assert robot.get("/v1/users/nobody").status_code == 404
