"""Staff corrections through the API: made, listed and lifted with the contract's errors; each
kind changes the robot's next decisions as stated; the person's contradicting answers override
a ``prefers``; corrections are audited, replayed by ``models rebuild`` to the identical model,
kept by export/import and by a reset unless it drops them."""

from __future__ import annotations

import json
import random
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.settings import Settings
from tests.support import people
from tests.support.commands import rebuild
from tests.support.episodes import play, start

SLOT, SITUATION = "afternoon", "stretching"  # the helpers' event time and situation
TEA = {"service": "ProvideDrink", "detail": "tea"}


def correction(cid: str, kind: str = "prefers", **kw: Any) -> dict[str, Any]:
    body: dict[str, Any] = {
        "correction_id": cid,
        "time_slot": SLOT,
        "situation": SITUATION,
        "kind": kind,
    }
    if kind == "prefers":
        body.update(TEA)
    body.update(kw)
    return body


def make_user(staff: TestClient, user_id: str = "chen") -> None:
    assert staff.put(f"/v1/users/{user_id}", json={}).status_code in (200, 201)


def meet(
    robot: TestClient,
    user_id: str,
    n: int,
    prefix: str,
    *,
    need: Any = people.TEA,
    picky: bool = True,
    seed: int = 0,
    situation: str = SITUATION,
) -> list[list[dict[str, Any]]]:
    """``n`` robot-initiated episodes of a person who wants ``need`` (and gives no feedback);
    the decisions of each."""
    rng = random.Random(seed)

    def person(decision: dict[str, Any]) -> dict[str, Any]:
        said = people.answer(decision["action"], need=need, picky=picky, rng=rng)
        said.pop("feedback", None)
        return said

    return [
        play(robot, user_id, f"{prefix}-{i}", person, situation=situation).decisions
        for i in range(n)
    ]


def kinds(steps: list[dict[str, Any]]) -> list[tuple[str, str | None, str | None]]:
    return [
        (d["action"]["kind"], d["action"].get("service"), d["action"].get("detail")) for d in steps
    ]


class TestContract:
    def test_made_listed_replayed_and_audited(self, staff: TestClient) -> None:
        make_user(staff)
        r = staff.post(
            "/v1/users/chen/corrections", json=correction("c1", note="Her daughter says so.")
        )
        assert r.status_code == 201, r.text
        made = r.json()
        assert made["status"] == "in_force"
        assert made["author"]
        assert made["note"] == "Her daughter says so."
        again = staff.post(
            "/v1/users/chen/corrections", json=correction("c1", note="Her daughter says so.")
        )
        assert again.status_code == 200
        assert again.headers["Idempotent-Replay"] == "true"
        assert again.json()["model_version"] == made["model_version"]
        clash = staff.post("/v1/users/chen/corrections", json=correction("c1", kind="quiet"))
        assert clash.status_code == 409
        [listed] = staff.get("/v1/users/chen/corrections").json()["items"]
        assert listed["correction_id"] == "c1"
        model = staff.get("/v1/users/chen/model").json()
        assert model["version"] == made["model_version"]  # counted in the model's version
        audit = staff.get("/v1/admin/audit").json()["items"]
        assert any(e["action"] == "correction.add" and e["target"] == "chen" for e in audit)

    @pytest.mark.parametrize(
        ("body", "word"),
        [
            (correction("x", time_slot="midnight"), "time slot"),
            (correction("x", situation="sleeping"), "situation"),
            (correction("x", service="Dance"), "service"),
            (correction("x", detail="whisky"), "detail"),
            (correction("x", service=None, detail=None), "needs a service"),
            (correction("x", detail=None), "needs a detail"),
            (correction("x", kind="quiet", service="ProvideDrink"), "quiet takes no service"),
            (correction("x", kind="avoid"), "needs a service"),
            (correction("x", kind="never"), "kind"),
            (correction("x/y"), "correction_id"),
        ],
    )
    def test_bad_input_is_422(self, staff: TestClient, body: dict[str, Any], word: str) -> None:
        make_user(staff)
        r = staff.post("/v1/users/chen/corrections", json=body)
        assert r.status_code == 422, r.text
        assert word in json.dumps(r.json()), r.json()
        assert staff.get("/v1/users/chen/corrections").json()["items"] == []

    def test_who_may(
        self, staff: TestClient, robot: TestClient, other_staff: TestClient, admin: TestClient
    ) -> None:
        make_user(staff)
        assert robot.post("/v1/users/chen/corrections", json=correction("r")).status_code == 403
        assert (
            other_staff.post("/v1/users/chen/corrections", json=correction("o")).status_code == 404
        )
        assert other_staff.get("/v1/users/chen/profile").status_code == 404
        assert admin.post("/v1/users/chen/corrections", json=correction("a")).status_code == 201
        assert robot.get("/v1/users/chen/profile").status_code == 200
        assert robot.delete("/v1/users/chen/corrections/a").status_code == 403
        assert other_staff.delete("/v1/users/chen/corrections/a").status_code == 404
        assert staff.delete("/v1/users/chen/corrections/nope").status_code == 404
        assert staff.post("/v1/users/nobody/corrections", json=correction("n")).status_code == 404


class TestDecisions:
    def test_prefers_performs_without_asking(self, staff: TestClient, robot: TestClient) -> None:
        make_user(staff)
        assert staff.post("/v1/users/chen/corrections", json=correction("tea")).status_code == 201
        episodes = meet(robot, "chen", 30, "p", picky=False)
        direct = [
            k
            for k in map(kinds, episodes)
            if k == [("initiate", None, None), ("perform", "ProvideDrink", "tea")]
        ]
        assert len(direct) >= 27  # at least 90 % of the draws
        profile = robot.get("/v1/users/chen/profile").json()
        cell = _cell(profile)
        assert cell["wants"] == TEA
        assert cell["source"] == "staff"
        assert cell["robot_will"]["action"] == "offer"
        assert cell["robot_will"]["service"] == "ProvideDrink"
        assert cell["robot_will"]["detail"] == "tea"

    def test_avoid_never_performs_it(self, staff: TestClient, robot: TestClient) -> None:
        make_user(staff)
        body = correction("no-drinks", kind="avoid", service="ProvideDrink", detail=None)
        assert staff.post("/v1/users/chen/corrections", json=body).status_code == 201
        # a person who goes along with anything, and wants a drink: the robot must not offer
        # one (when it waits and the person asks for a drink by name, it serves the request)
        episodes = meet(robot, "chen", 25, "a", picky=False)
        offered = [k for k in map(kinds, episodes) if k[0][0] == "initiate"]
        assert all(k[1] != "ProvideDrink" for steps in offered for k in steps)
        # and its distributions there give a drink no chance on its own initiative
        model = robot.get(f"/v1/users/chen/model?time_slot={SLOT}&situation={SITUATION}")
        [context] = model.json()["contexts"]
        engaged = next(s for s in context["states"] if s["state"] == "ENGAGED")
        for a in engaged["actions"]:
            if a["action"].get("service") == "ProvideDrink" or a["action"]["kind"] == "query_type":
                assert a["p"] == 0.0, a
        others = [a["p"] for a in engaged["actions"] if a["p"] > 0]
        assert others
        assert sum(others) == pytest.approx(1.0)

    def test_avoid_a_detail(self, staff: TestClient, robot: TestClient) -> None:
        make_user(staff)
        body = correction("no-tea", kind="avoid", service="ProvideDrink", detail="tea")
        assert staff.post("/v1/users/chen/corrections", json=body).status_code == 201
        episodes = meet(robot, "chen", 25, "d", picky=False)
        assert all(
            k != ("perform", "ProvideDrink", "tea") for steps in episodes for k in kinds(steps)
        )

    def test_quiet_never_initiates_but_answers_requests(
        self, staff: TestClient, robot: TestClient
    ) -> None:
        make_user(staff)
        quiet = correction("hush", kind="quiet", service=None, detail=None)
        assert staff.post("/v1/users/chen/corrections", json=quiet).status_code == 201
        for i in range(20):
            first = start(robot, "chen", f"q-{i}")["decision"]
            assert first["action"]["kind"] == "pass"
        asked = start(robot, "chen", "q-ask", initiator="human", request=TEA)
        assert asked["decision"]["action"]["kind"] == "perform"
        profile = robot.get("/v1/users/chen/profile").json()
        assert _cell(profile)["robot_will"]["action"] == "stay_away"

    def test_lifting_restores_the_learner(self, staff: TestClient, robot: TestClient) -> None:
        # HRI: its probabilities are exact (the DTS family's are estimated from posterior
        # draws seeded by the model version, which a correction and its lift move on by two).
        assert (
            staff.put("/v1/users/chen", json={"learner": {"algorithm": "hri"}}).status_code == 201
        )
        quiet = correction("hush", kind="quiet", service=None, detail=None)
        before = robot.get("/v1/users/chen/model").json()
        assert staff.post("/v1/users/chen/corrections", json=quiet).status_code == 201
        assert staff.delete("/v1/users/chen/corrections/hush").status_code == 204
        assert staff.delete("/v1/users/chen/corrections/hush").status_code == 204  # no change
        after = robot.get("/v1/users/chen/model").json()
        assert after["version"] == before["version"] + 2
        assert _probabilities(after) == _probabilities(before)
        [item] = staff.get("/v1/users/chen/corrections").json()["items"]
        assert item["status"] == "lifted"
        assert item["lifted_by"]
        audit = staff.get("/v1/admin/audit").json()["items"]
        assert [e["action"] for e in audit].count("correction.lift") == 1

    def test_the_person_wins(self, staff: TestClient, robot: TestClient) -> None:
        make_user(staff)
        assert staff.post("/v1/users/chen/corrections", json=correction("tea")).status_code == 201
        coffee = ("ProvideDrink", "coffee")
        meet(robot, "chen", 6, "w", need=coffee)  # turns tea down, asks for coffee
        [item] = staff.get("/v1/users/chen/corrections").json()["items"]
        assert item["status"] == "overridden"
        assert item["overridden_at"] is not None
        cell = _cell(robot.get("/v1/users/chen/profile").json())
        assert cell["source"] != "staff"
        assert cell["changed"] is not None
        assert cell["changed"]["overrides"] == "tea"
        assert cell["changed"]["before"] == TEA
        # the robot no longer brings tea without asking nearly always
        episodes = meet(robot, "chen", 10, "w2", need=coffee, seed=1)
        direct_tea = [k for k in map(kinds, episodes) if ("perform", "ProvideDrink", "tea") in k]
        assert len(direct_tea) < 9


class TestHistory:
    def test_rebuild_is_identical(
        self, staff: TestClient, robot: TestClient, settings: Settings
    ) -> None:
        make_user(staff)
        meet(robot, "chen", 3, "h1")
        staff.post("/v1/users/chen/corrections", json=correction("tea"))
        meet(robot, "chen", 3, "h2", need=("ProvideDrink", "coffee"))
        staff.post(
            "/v1/users/chen/corrections",
            json=correction("hush", kind="quiet", service=None, detail=None, time_slot="morning"),
        )
        meet(robot, "chen", 2, "h3")
        staff.delete("/v1/users/chen/corrections/hush")
        meet(robot, "chen", 2, "h4")
        summary = rebuild(settings.database_url, "chen", pooler=settings.database_pooler).summary
        assert summary["identical"] is True, summary

    def test_export_import_and_reset(
        self, staff: TestClient, robot: TestClient, settings: Settings
    ) -> None:
        make_user(staff)
        staff.post("/v1/users/chen/corrections", json=correction("tea"))
        doc = staff.get("/v1/users/chen/model/export").json()
        assert [r["id"] for r in doc["guidance"]] == ["tea"]
        assert staff.delete("/v1/users/chen/model").status_code == 204  # keeps corrections
        assert _statuses(staff) == {"tea": "in_force"}
        assert staff.delete("/v1/users/chen/model?corrections=drop").status_code == 204
        assert _statuses(staff) == {"tea": "lifted"}
        assert _cell(robot.get("/v1/users/chen/profile").json())["source"] is None
        assert staff.put("/v1/users/chen/model", json=doc).status_code == 200
        assert _statuses(staff) == {"tea": "in_force"}
        meet(robot, "chen", 2, "e")
        assert (
            rebuild(settings.database_url, "chen", pooler=settings.database_pooler).summary[
                "identical"
            ]
            is True
        )

    def test_bad_guidance_in_an_import_is_422(self, staff: TestClient) -> None:
        make_user(staff)
        doc = staff.get("/v1/users/chen/model/export").json()
        doc["guidance"] = [
            {"id": "x", "kind": "sometimes", "time_slot": SLOT, "situation": SITUATION}
        ]
        r = staff.put("/v1/users/chen/model", json=doc)
        assert r.status_code == 422
        assert "guidance" in r.text


def _cell(profile: dict[str, Any], slot: str = SLOT, situation: str = SITUATION) -> dict[str, Any]:
    cells: list[dict[str, Any]] = [
        c for c in profile["contexts"] if (c["time_slot"], c["situation"]) == (slot, situation)
    ]
    assert len(cells) == 1
    return cells[0]


def _probabilities(model: dict[str, Any]) -> list[float]:
    return [a["p"] for c in model["contexts"] for s in c["states"] for a in s["actions"]]


def _statuses(staff: TestClient) -> dict[str, str]:
    items = staff.get("/v1/users/chen/corrections").json()["items"]
    return {i["correction_id"]: i["status"] for i in items}
