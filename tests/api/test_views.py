"""Who looked at a person (docs/api.md, "Who looked"): every read of a person's data by a staff
or admin key is recorded, through the API and the console, before it is answered; robots'
reads, 404s, the list of people and reading the record itself are not. Staff see their fleet's,
admins every fleet's; the entries go with the person and after the window."""

from __future__ import annotations

import datetime as dt
import html
import re
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from app.db.models import DataView
from app.db.repositories import views as views_repo
from app.db.session import Database
from app.db.types import utcnow
from app.settings import Settings
from tests.support.contract import assert_error
from tests.support.episodes import play
from tests.support.fixtures import MakeKey
from tests.support.people import person

LIN = "lin"


def _views(client: TestClient, path: str = f"/v1/users/{LIN}/views", **params: Any) -> list[Any]:
    r = client.get(path, params=params)
    assert r.status_code == 200, r.text
    items: list[Any] = r.json()["items"]
    return items


def _count(db: Database) -> int:
    with db.engine.connect() as conn:
        return int(conn.scalar(select(func.count()).select_from(DataView.__table__)) or 0)


@pytest.fixture
def night(app: FastAPI, make_key: MakeKey) -> Iterator[TestClient]:
    """A staff key of fleet ``default`` named ``night-shift``."""
    key = make_key("staff", "default", "night-shift")
    with TestClient(app, headers={"Authorization": f"Bearer {key}"}) as c:
        yield c


@pytest.fixture
def lin(robot: TestClient) -> str:
    """Lin, with two finished episodes: the id of the last."""
    assert robot.put(f"/v1/users/{LIN}", json={"display_name": "Mrs. Lin"}).status_code == 201
    last = ""
    for i in range(2):
        last = play(robot, LIN, f"e{i}", person(picky=False)).episode_id
    return last


READS = [
    (f"/v1/users/{LIN}", "user"),
    (f"/v1/users/{LIN}/model", "model"),
    (f"/v1/users/{LIN}/stats", "stats"),
    (f"/v1/users/{LIN}/profile", "profile"),
    (f"/v1/users/{LIN}/corrections", "corrections"),
    (f"/v1/users/{LIN}/episodes", "episodes"),
    ("/v1/episodes/{episode}", "episode"),
    (f"/v1/users/{LIN}/model/export", "export"),
]


def test_every_staff_read_is_recorded_newest_first(
    lin: str, night: TestClient, robot: TestClient, db: Database
) -> None:
    before = utcnow()
    for path, _ in READS:
        assert night.get(path.format(episode=lin)).status_code == 200, path
    items = _views(night)
    assert [e["what"] for e in items] == [what for _, what in reversed(READS)]
    for e in items:
        assert (e["user_id"], e["fleet"], e["via"]) == (LIN, "default", "api")
        assert (e["actor"]["role"], e["actor"]["name"]) == ("staff", "night-shift")
        assert dt.datetime.fromisoformat(e["at"]) >= before - dt.timedelta(seconds=1)
    # Robots' reads, a read that found nothing, the list, and this record: not recorded.
    count = _count(db)
    for path, _ in READS[:-1]:  # the export is staff's
        assert robot.get(path.format(episode=lin)).status_code == 200, path
    assert night.get("/v1/users/nobody/model").status_code == 404
    assert night.head(f"/v1/users/{LIN}/model").status_code == 200  # no data sent
    assert night.get("/v1/users").status_code == 200
    _views(night)
    _views(night, "/v1/admin/views")
    assert _count(db) == count


def test_who_sees_the_record(
    lin: str,
    night: TestClient,
    admin: TestClient,
    robot: TestClient,
    other_staff: TestClient,
    other_robot: TestClient,
) -> None:
    assert other_robot.put("/v1/users/far", json={}).status_code == 201
    assert other_staff.get("/v1/users/far/profile").status_code == 200
    assert admin.get(f"/v1/users/{LIN}/profile").status_code == 200
    assert admin.get("/v1/users/far/model", params={"fleet": "other"}).status_code == 200
    # Staff: their fleet's only.
    assert [(e["user_id"], e["actor"]["role"]) for e in _views(night, "/v1/admin/views")] == [
        (LIN, "admin")
    ]
    assert [e["what"] for e in _views(other_staff, "/v1/admin/views")] == ["model", "profile"]
    assert_error(night.get("/v1/admin/views", params={"fleet": "other"}), 404, "NotFound")
    assert_error(other_staff.get(f"/v1/users/{LIN}/views"), 404, "NotFound")
    assert_error(robot.get(f"/v1/users/{LIN}/views"), 403, "Forbidden")
    assert_error(robot.get("/v1/admin/views"), 403, "Forbidden")
    # Admins: every fleet's, or one's; the admin's read of another fleet is that fleet's.
    every = _views(admin, "/v1/admin/views")
    assert [(e["fleet"], e["user_id"]) for e in every] == [
        ("other", "far"),
        ("default", LIN),
        ("other", "far"),
    ]
    assert {e["fleet"] for e in _views(admin, "/v1/admin/views", fleet="other")} == {"other"}
    assert len(_views(admin, "/v1/users/far/views", fleet="other")) == 2


def test_pages_of_the_record(lin: str, night: TestClient) -> None:
    for _ in range(5):
        assert night.get(f"/v1/users/{LIN}").status_code == 200
    first = night.get(f"/v1/users/{LIN}/views", params={"limit": 2}).json()
    second = night.get(
        f"/v1/users/{LIN}/views", params={"limit": 2, "cursor": first["next_cursor"]}
    ).json()
    ids = [int(e["id"]) for e in first["items"] + second["items"]]
    assert ids == sorted(ids, reverse=True)
    assert len(set(ids)) == 4
    assert_error(
        night.get(f"/v1/users/{LIN}/views", params={"cursor": "x"}), 422, "ValidationError"
    )


def test_the_record_goes_with_the_person(lin: str, night: TestClient, db: Database) -> None:
    assert night.get(f"/v1/users/{LIN}/model").status_code == 200
    assert _count(db) == 1
    assert night.delete(f"/v1/users/{LIN}").status_code == 204
    assert _count(db) == 0
    assert _views(night, "/v1/admin/views") == []


@pytest.fixture
def settings(settings: Settings, request: pytest.FixtureRequest) -> Settings:
    """The shared settings; ``@pytest.mark.view_log_days(N)`` sets the window."""
    marker = request.node.get_closest_marker("view_log_days")
    if marker is None:
        return settings
    return settings.model_copy(update={"view_log_days": marker.args[0]})


def _old_entries(db: Database, days_ago: int) -> None:
    """An entry ``days_ago`` old of Lin (default) and of Far (other)."""
    old = utcnow() - dt.timedelta(days=days_ago)
    with db.transaction(write=True) as session:
        for fleet, uid in (("default", LIN), ("other", "far")):
            views_repo.add(
                session,
                fleet=fleet,
                user_id=uid,
                at=old,
                actor=("key_x", "staff", fleet),
                what="model",
                via="api",
            )


@pytest.mark.view_log_days(30)
def test_entries_older_than_the_window_go_as_the_fleets_new_ones_come(
    lin: str, night: TestClient, other_staff: TestClient, other_robot: TestClient, db: Database
) -> None:
    assert other_robot.put("/v1/users/far", json={}).status_code == 201
    _old_entries(db, 31)
    _old_entries(db, 29)
    assert night.get(f"/v1/users/{LIN}/model").status_code == 200
    assert [e["actor"]["key_id"] for e in _views(night)][1:] == ["key_x"]  # 29 days: kept
    assert len(_views(other_staff, "/v1/users/far/views")) == 2  # another fleet's: not yet


@pytest.mark.view_log_days(0)
def test_a_window_of_0_keeps_them_until_the_person_is_erased(
    lin: str, night: TestClient, db: Database
) -> None:
    _old_entries(db, 3650)
    assert night.get(f"/v1/users/{LIN}/model").status_code == 200
    assert len(_views(night)) == 2


def test_the_console_records_each_page_and_shows_who_looked_before(
    lin: str, app: FastAPI, make_key: MakeKey, night: TestClient
) -> None:
    key = make_key("staff", "default", "day-shift")
    with TestClient(app, follow_redirects=False) as console:
        console.cookies.set("attune_console", key, path="/admin")
        first = console.get(f"/admin/users/{LIN}")
        assert first.status_code == 200, first.text
        assert "No earlier look at this person" in first.text
        assert night.get(f"/v1/users/{LIN}/profile").status_code == 200
        pages = {}
        for tail in ("/details", "/episodes", "/why", "/export", ""):
            r = console.get(f"/admin/users/{LIN}{tail}")
            assert r.status_code == 200, (tail, r.text[:300])
            pages[tail] = r.text
    # The details page, just after night-shift read the profile through the API.
    looked = re.search(r'<p class="muted small" id="looked">(.*?)</p>', pages["/details"])
    assert looked is not None
    said = html.unescape(re.sub(r"<[^>]+>", "", looked[1]))
    assert re.match(r"Looked at before by night-shift, .*\(the API's profile\); you, ", said), said
    items = _views(night)
    assert [(e["what"], e["via"]) for e in items[:6]] == [
        ("console.profile", "console"),
        ("export", "console"),
        ("console.why", "console"),
        ("console.episodes", "console"),
        ("console.details", "console"),
        ("profile", "api"),
    ]
    assert {e["actor"]["name"] for e in items if e["via"] == "console"} == {"day-shift"}
