"""Users: PUT (create/update), GET, list with pagination, DELETE; fleets and roles."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.learning import DtsRoutineParams
from tests.support.contract import assert_error
from tests.support.episodes import report, start


class TestPutUser:
    def test_create_is_201_with_the_user_object(self, robot: TestClient) -> None:
        r = robot.put("/v1/users/lin", json={"display_name": "Mrs. Lin"})
        assert r.status_code == 201, r.text
        body = r.json()
        assert set(body) >= {
            "user_id",
            "fleet",
            "display_name",
            "learner",
            "created_at",
            "episodes",
        }
        assert body["user_id"] == "lin"
        assert body["fleet"] == "default"
        assert body["display_name"] == "Mrs. Lin"
        assert body["episodes"] == 0
        assert isinstance(body["created_at"], str)
        assert body["created_at"]

    def test_default_learner_is_dts_routine_with_its_defaults(self, robot: TestClient) -> None:
        # The learner the robustness suite's rule picks (docs/method.md §12, Robustness).
        r = robot.put("/v1/users/lin")
        assert r.status_code == 201, r.text
        learner = r.json()["learner"]
        assert learner["algorithm"] == "dts-routine"
        assert learner["params"] == DtsRoutineParams().to_dict()

    def test_empty_object_body_creates_with_defaults(self, robot: TestClient) -> None:
        r = robot.put("/v1/users/lin", json={})
        assert r.status_code == 201, r.text
        assert r.json()["learner"]["algorithm"] == "dts-routine"
        assert r.json()["display_name"] is None

    def test_update_is_200(self, robot: TestClient, staff: TestClient) -> None:
        assert robot.put("/v1/users/lin", json={"display_name": "A"}).status_code == 201
        r = staff.put("/v1/users/lin", json={"display_name": "B"})
        assert r.status_code == 200, r.text
        assert r.json()["display_name"] == "B"
        assert robot.get("/v1/users/lin").json()["display_name"] == "B"

    def test_same_body_again_is_200_and_changes_nothing(self, robot: TestClient) -> None:
        body = {
            "display_name": "Mrs. Lin",
            "learner": {"algorithm": "hri", "params": {"tau": 0.01}},
        }
        first = robot.put("/v1/users/lin", json=body)
        assert first.status_code == 201
        model_before = robot.get("/v1/users/lin/model").json()
        second = robot.put("/v1/users/lin", json=body)
        assert second.status_code == 200
        assert second.json() == first.json()
        assert robot.get("/v1/users/lin").json() == first.json()
        assert robot.get("/v1/users/lin/model").json() == model_before

    def test_omitted_fields_keep_their_values(self, robot: TestClient) -> None:
        robot.put(
            "/v1/users/lin", json={"display_name": "Mrs. Lin", "learner": {"algorithm": "rmax"}}
        )
        r = robot.put("/v1/users/lin", json={})
        assert r.status_code == 200
        assert r.json()["display_name"] == "Mrs. Lin"
        assert r.json()["learner"]["algorithm"] == "rmax"

    @pytest.mark.parametrize("algorithm", ["hri", "rmax", "qlearning"])
    def test_each_shipped_learner_is_accepted(self, robot: TestClient, algorithm: str) -> None:
        r = robot.put("/v1/users/lin", json={"learner": {"algorithm": algorithm}})
        assert r.status_code == 201, r.text
        assert r.json()["learner"]["algorithm"] == algorithm
        assert robot.get("/v1/users/lin/model").json()["algorithm"] == algorithm

    def test_params_are_kept(self, robot: TestClient) -> None:
        r = robot.put(
            "/v1/users/lin", json={"learner": {"algorithm": "hri", "params": {"tau": 0.005}}}
        )
        assert r.status_code == 201
        assert r.json()["learner"]["params"]["tau"] == pytest.approx(0.005)

    def test_unknown_algorithm_is_422_naming_the_allowed_ones(self, robot: TestClient) -> None:
        r = robot.put("/v1/users/lin", json={"learner": {"algorithm": "sarsa"}})
        body = assert_error(r, 422, "ValidationError")
        for name in ("hri", "rmax", "qlearning"):
            assert name in body["detail"]
        assert robot.get("/v1/users/lin").status_code == 404

    @pytest.mark.parametrize(
        "params",
        [
            {"tau": -1},
            {"tau": "hot"},
            {"nope": 1},
            {"tau": None},
            {"measure": "yes"},
        ],
    )
    def test_bad_params_are_422(self, robot: TestClient, params: dict[str, Any]) -> None:
        r = robot.put("/v1/users/lin", json={"learner": {"algorithm": "hri", "params": params}})
        assert_error(r, 422, "ValidationError")
        assert robot.get("/v1/users/lin").status_code == 404

    def test_unknown_param_names_the_allowed_ones(self, robot: TestClient) -> None:
        r = robot.put(
            "/v1/users/lin", json={"learner": {"algorithm": "hri", "params": {"temperature": 1}}}
        )
        body = assert_error(r, 422, "ValidationError")
        assert "tau" in body["detail"]

    def test_bad_params_on_update_change_nothing(
        self, robot: TestClient, staff: TestClient
    ) -> None:
        robot.put("/v1/users/lin", json={"display_name": "A"})
        before = robot.get("/v1/users/lin").json()
        model = robot.get("/v1/users/lin/model").json()
        r = staff.put(
            "/v1/users/lin",
            json={"display_name": "B", "learner": {"algorithm": "hri", "params": {"tau": -3}}},
        )
        assert_error(r, 422, "ValidationError")
        assert robot.get("/v1/users/lin").json() == before
        assert robot.get("/v1/users/lin/model").json() == model

    def test_changing_learner_without_history_is_allowed(
        self, robot: TestClient, staff: TestClient
    ) -> None:
        robot.put("/v1/users/lin")
        r = staff.put("/v1/users/lin", json={"learner": {"algorithm": "qlearning"}})
        assert r.status_code == 200, r.text
        assert r.json()["learner"]["algorithm"] == "qlearning"

    def test_changing_learner_with_history_is_409(
        self, robot: TestClient, staff: TestClient
    ) -> None:
        start(robot, "lin", "e1")
        before = robot.get("/v1/users/lin").json()
        model = robot.get("/v1/users/lin/model").json()
        r = staff.put("/v1/users/lin", json={"display_name": "X", "learner": {"algorithm": "rmax"}})
        assert_error(r, 409, "Conflict")
        assert "reset_model" in r.json()["detail"]
        assert robot.get("/v1/users/lin").json() == before
        assert robot.get("/v1/users/lin/model").json() == model

    def test_changing_params_with_history_is_409(
        self, robot: TestClient, staff: TestClient
    ) -> None:
        start(robot, "lin", "e1")
        r = staff.put(
            "/v1/users/lin", json={"learner": {"algorithm": "hri", "params": {"tau": 0.005}}}
        )
        assert_error(r, 409, "Conflict")

    def test_same_learner_with_history_is_fine(self, robot: TestClient) -> None:
        start(robot, "lin", "e1")  # created with the default learner
        r = robot.put(
            "/v1/users/lin",
            json={"learner": {"algorithm": "dts-routine", "params": {"forgetting": 0.95}}},
        )
        assert r.status_code == 200, r.text

    def test_reset_model_true_allows_the_change_and_keeps_history(
        self, robot: TestClient, staff: TestClient
    ) -> None:
        ep = start(robot, "lin", "e1")
        report(
            robot,
            ep["episode_id"],
            ep["decision"]["decision_id"],
            "rejected" if ep["decision"]["action"]["kind"] == "initiate" else "none",
        )
        version = robot.get("/v1/users/lin/model").json()["version"]
        r = staff.put("/v1/users/lin?reset_model=true", json={"learner": {"algorithm": "rmax"}})
        assert r.status_code == 200, r.text
        assert r.json()["learner"]["algorithm"] == "rmax"
        assert r.json()["episodes"] == 1
        model = robot.get("/v1/users/lin/model").json()
        assert model["algorithm"] == "rmax"
        assert model["version"] > version
        assert all(
            a["visits"] == 0 for c in model["contexts"] for s in c["states"] for a in s["actions"]
        )
        assert robot.get(f"/v1/episodes/{ep['episode_id']}").status_code == 200

    @pytest.mark.one_engine
    def test_extra_fields_are_422(self, robot: TestClient) -> None:
        r = robot.put("/v1/users/lin", json={"display_name": "A", "age": 3})
        assert_error(r, 422, "ValidationError")
        assert robot.get("/v1/users/lin").status_code == 404

    def test_another_fleet_makes_its_own_user_of_the_same_id(
        self, robot: TestClient, other_robot: TestClient, other_staff: TestClient
    ) -> None:
        robot.put("/v1/users/lin", json={"display_name": "A"})
        before = robot.get("/v1/users/lin").json()
        r = other_robot.put("/v1/users/lin", json={"display_name": "B"})
        assert r.status_code == 201, r.text
        assert (r.json()["fleet"], r.json()["display_name"]) == ("other", "B")
        assert robot.get("/v1/users/lin").json() == before
        assert other_staff.put("/v1/users/lin", json={"display_name": "B2"}).status_code == 200
        assert robot.get("/v1/users/lin").json() == before


class TestGetUser:
    def test_absent_is_404(self, robot: TestClient) -> None:
        assert_error(robot.get("/v1/users/nobody"), 404, "NotFound")

    def test_returns_the_user_object(self, robot: TestClient) -> None:
        created = robot.put("/v1/users/lin", json={"display_name": "Mrs. Lin"}).json()
        r = robot.get("/v1/users/lin")
        assert r.status_code == 200
        assert r.json() == created

    def test_episodes_counts_the_users_episodes(self, robot: TestClient) -> None:
        start(robot, "lin", "e1")
        start(robot, "lin", "e2")
        assert robot.get("/v1/users/lin").json()["episodes"] == 2

    def test_another_fleets_user_is_404(self, robot: TestClient, other_robot: TestClient) -> None:
        robot.put("/v1/users/lin")
        assert_error(other_robot.get("/v1/users/lin"), 404, "NotFound")

    def test_admin_reads_every_fleet(self, other_robot: TestClient, admin: TestClient) -> None:
        other_robot.put("/v1/users/far")
        r = admin.get("/v1/users/far", params={"fleet": "other"})
        assert r.status_code == 200
        assert r.json()["fleet"] == "other"
        # Without ?fleet= the admin's own fleet is meant, where there is no far.
        assert_error(admin.get("/v1/users/far"), 404, "NotFound")

    def test_only_admins_name_a_fleet(self, robot: TestClient, other_robot: TestClient) -> None:
        other_robot.put("/v1/users/far")
        assert_error(robot.get("/v1/users/far", params={"fleet": "other"}), 404, "NotFound")
        assert robot.get("/v1/users/nobody", params={"fleet": "default"}).status_code == 404
        assert other_robot.get("/v1/users/far", params={"fleet": "other"}).status_code == 200


class TestListUsers:
    def test_pages_cover_every_user_exactly_once(self, robot: TestClient) -> None:
        ids = sorted(f"user-{i:02d}" for i in range(7))
        for uid in ids:
            assert robot.put(f"/v1/users/{uid}").status_code == 201
        seen: list[str] = []
        cursor: str | None = None
        pages = 0
        while True:
            params: dict[str, Any] = {"limit": 3}
            if cursor is not None:
                params["cursor"] = cursor
            r = robot.get("/v1/users", params=params)
            assert r.status_code == 200, r.text
            page = r.json()
            assert set(page) >= {"items", "next_cursor"}
            assert len(page["items"]) <= 3
            seen += [u["user_id"] for u in page["items"]]
            pages += 1
            cursor = page["next_cursor"]
            if cursor is None:
                break
            assert pages < 10
        assert sorted(seen) == ids
        assert len(seen) == len(set(seen))
        assert pages == 3

    def test_exact_multiple_ends_with_null_cursor(self, robot: TestClient) -> None:
        for uid in ("a", "b", "c", "d"):
            robot.put(f"/v1/users/{uid}")
        first = robot.get("/v1/users", params={"limit": 2}).json()
        second = robot.get("/v1/users", params={"limit": 2, "cursor": first["next_cursor"]}).json()
        assert [u["user_id"] for u in first["items"] + second["items"]] == ["a", "b", "c", "d"]
        assert (
            second["next_cursor"] is None
            or robot.get("/v1/users", params={"limit": 2, "cursor": second["next_cursor"]}).json()[
                "items"
            ]
            == []
        )

    def test_default_lists_everyone_with_null_cursor(self, robot: TestClient) -> None:
        robot.put("/v1/users/a")
        robot.put("/v1/users/b")
        page = robot.get("/v1/users").json()
        assert [u["user_id"] for u in page["items"]] == ["a", "b"]
        assert page["next_cursor"] is None

    def test_items_are_user_objects(self, robot: TestClient) -> None:
        created = robot.put("/v1/users/a", json={"display_name": "A"}).json()
        assert robot.get("/v1/users").json()["items"] == [created]

    def test_robot_sees_only_its_fleet_admin_sees_all(
        self, robot: TestClient, other_robot: TestClient, admin: TestClient
    ) -> None:
        robot.put("/v1/users/mine")
        other_robot.put("/v1/users/theirs")
        assert [u["user_id"] for u in robot.get("/v1/users").json()["items"]] == ["mine"]
        assert [u["user_id"] for u in other_robot.get("/v1/users").json()["items"]] == ["theirs"]
        every = {u["user_id"]: u["fleet"] for u in admin.get("/v1/users").json()["items"]}
        assert every == {"mine": "default", "theirs": "other"}

    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        "query", ["limit=0", "limit=-1", "limit=abc", "limit=100000", "cursor=%25%25%25"]
    )
    def test_bad_paging_is_422(self, robot: TestClient, query: str) -> None:
        robot.put("/v1/users/a")
        assert_error(robot.get(f"/v1/users?{query}"), 422, "ValidationError")

    @pytest.mark.one_engine
    def test_needs_a_key(self, client: TestClient) -> None:
        assert_error(client.get("/v1/users"), 401, "Unauthorized")


class TestDeleteUser:
    @pytest.mark.one_engine
    def test_robot_is_403_and_nothing_changes(self, robot: TestClient) -> None:
        start(robot, "lin", "e1")
        before = robot.get("/v1/users/lin").json()
        assert_error(robot.delete("/v1/users/lin"), 403, "Forbidden")
        assert robot.get("/v1/users/lin").json() == before

    def test_admin_removes_user_history_and_model(
        self, robot: TestClient, admin: TestClient
    ) -> None:
        ep = start(robot, "lin", "e1")
        r = admin.delete("/v1/users/lin")
        assert r.status_code == 204
        assert r.content == b""
        assert_error(robot.get("/v1/users/lin"), 404, "NotFound")
        assert_error(robot.get(f"/v1/episodes/{ep['episode_id']}"), 404, "NotFound")
        assert_error(robot.get("/v1/users/lin/model"), 404, "NotFound")
        assert_error(robot.get("/v1/users/lin/stats"), 404, "NotFound")

    def test_a_deleted_user_starts_over(self, robot: TestClient, admin: TestClient) -> None:
        start(robot, "lin", "e1")
        admin.delete("/v1/users/lin")
        again = robot.post(
            "/v1/users/lin/episodes",
            json={
                "event_id": "e1",
                "occurred_at": "2026-11-22T15:10:00+08:00",
                "situation": "stretching",
                "initiator": "robot",
            },
        )
        assert again.status_code == 201, again.text
        assert robot.get("/v1/users/lin").json()["episodes"] == 1

    def test_absent_is_404(self, admin: TestClient) -> None:
        assert_error(admin.delete("/v1/users/nobody"), 404, "NotFound")

    def test_other_fleet_admin_sees_all(self, other_robot: TestClient, admin: TestClient) -> None:
        other_robot.put("/v1/users/far")
        assert admin.delete("/v1/users/far", params={"fleet": "other"}).status_code == 204
        assert_error(other_robot.get("/v1/users/far"), 404, "NotFound")
