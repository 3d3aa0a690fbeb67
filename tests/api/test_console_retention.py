"""The console's page of a fleet's retention window (``/admin/retention``), without a browser,
on both engines: the window in words, set through the form with the same service as ``PUT
/v1/admin/fleets/{fleet}/history`` (validated and audited there, once), mistakes said on the form
with what was typed, the CSRF and fleet rules of the other forms, the last clean-up and what it
removed, and on each page of a person the date from which their history is kept."""

from __future__ import annotations

import datetime as dt
import html
import re
import zoneinfo
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.daily import DailyTime
from app.main import create_app
from app.services import retention
from app.settings import Settings
from tests.support import people
from tests.support.episodes import report, start
from tests.support.fixtures import MakeKey

FLEET = "north"
ZONE = "Asia/Shanghai"


def _words(page: str, where: str) -> str:
    """The text of the element with id ``where`` (to its first closing tag of that kind)."""
    found = re.search(rf'<(\w+)[^>]* id="{where}"[^>]*>(.*?)</\1>', page, flags=re.S)
    assert found, where
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", "", found.group(2)))).strip()


class Console:
    """A browser signed in with a staff key of ``north`` (``api``: the same key on the v1
    API), whose robot made ``lin`` with three finished episodes and one open."""

    def __init__(self, client: TestClient, api: TestClient) -> None:
        self.client, self.api = client, api

    def page(self, path: str = "/admin/retention") -> httpx.Response:
        r: httpx.Response = self.client.get(path)
        assert r.status_code == 200, r.text
        return r

    def form(self, path: str = "/admin/retention", **fields: str) -> dict[str, str]:
        block = self.page(path).text.split('id="window-form"')[1].split("</form>")[0]
        hidden = dict(re.findall(r'<input type="hidden" name="(\w+)" value="([^"]*)"', block))
        return {**{k: html.unescape(v) for k, v in hidden.items()}, **fields}

    def post(
        self, form: dict[str, str], path: str = "/admin/retention", **kw: Any
    ) -> httpx.Response:
        r: httpx.Response = self.client.post(path, data=form, **kw)
        return r

    def window(self) -> int | None:
        r = self.api.get(f"/v1/admin/fleets/{FLEET}/history")
        assert r.status_code == 200, r.text
        days: int | None = r.json()["history_days"]
        return days

    def audit(self, action: str) -> list[dict[str, Any]]:
        items = self.api.get("/v1/admin/audit", params={"limit": 100}).json()["items"]
        return [e for e in items if e["action"] == action]


def _play(robot: TestClient) -> None:
    for n in range(3):
        episode = start(
            robot,
            "lin",
            f"e{n}",
            situation="stretching",
            occurred_at=f"2026-11-2{n}T15:10:00+08:00",
        )
        decision = episode["decision"]
        while decision is not None:
            fields = people.answer(decision["action"], need=people.TEA)
            decision = report(robot, episode["episode_id"], decision["decision_id"], **fields)[
                "decision"
            ]
    start(robot, "lin", "open", situation="working", occurred_at="2026-11-23T09:30:00+08:00")


def _console(app: FastAPI, make_key: MakeKey, *, name: str = "night-shift") -> Iterator[Console]:
    robot = TestClient(app, headers={"Authorization": f"Bearer {make_key('robot', FLEET)}"})
    staff = make_key("staff", FLEET, name)
    api = TestClient(app, headers={"Authorization": f"Bearer {staff}"})
    client = TestClient(app, raise_server_exceptions=False, follow_redirects=False)
    client.cookies.set("attune_console", staff, path="/admin")
    with robot, api, client:
        office = api.get("/v1/mission").json()
        doc = {k: v for k, v in office.items() if k not in ("fleet", "version", "fingerprint")}
        zoned = api.put(
            f"/v1/admin/fleets/{FLEET}/mission",
            json={"change_id": "zone", "mission": {**doc, "time_zone": ZONE}},
        )
        assert zoned.status_code == 200, zoned.text
        assert robot.put("/v1/users/lin", json={"display_name": "Mrs. Lin"}).status_code == 201
        _play(robot)
        yield Console(client, api)


@pytest.fixture
def console(app: FastAPI, make_key: MakeKey) -> Iterator[Console]:
    yield from _console(app, make_key)


def test_a_fleet_keeps_everything_until_its_staff_choose(console: Console) -> None:
    page = console.page().text
    assert 'id="nav-retention" aria-current="page">History kept' in page
    assert _words(page, "retention-fleet").startswith("How long fleet north keeps")
    assert _words(page, "window-words") == "Every episode is kept until the person is erased."
    assert _words(page, "last-run") == "No clean-up has run for this fleet yet."
    assert _words(page, "window-set").startswith("Never changed: the fleet keeps everything")
    assert f"Times are in the fleet's time zone, {ZONE}." in _words(page, "window-set")
    assert re.search(r'id="keep-all" name="keep" value="all" checked', page)


def test_staff_set_the_window_and_read_it_back(console: Console) -> None:
    form = console.form(keep="days", days="90")
    saved = console.post(form)
    assert saved.status_code == 303, saved.text
    assert saved.headers["location"] == f"/admin/retention?fleet={FLEET}&done=saved"
    assert console.window() == 90  # what the API says
    page = console.page(saved.headers["location"]).text
    assert _words(page, "done-notice") == (
        "Saved. From the next clean-up on, episodes older than 90 days are removed."
    )
    assert _words(page, "window-words") == (
        "Episodes older than 90 days are removed each time the clean-up runs (your operator "
        "schedules it); what the robot learned from them is kept."
    )
    assert _words(page, "window-set").startswith("Set to 90 days on ")
    assert " by night-shift." in _words(page, "window-set")
    assert re.search(r'id="keep-days" name="keep" value="days" checked', page)
    assert re.search(r'id="days" name="days"[^>]* value="90"', page)
    # Audited once, by the same service as the API, with the staff member's key.
    (entry,) = console.audit("fleet.history")
    assert entry["detail"] == {"history_days": 90}
    assert entry["actor"]["role"] == "staff"
    assert entry["target"] == FLEET
    # A second press of Save changes nothing and adds no entry.
    assert console.post(form).status_code == 303
    assert len(console.audit("fleet.history")) == 1
    # Back to keeping everything.
    kept = console.post(console.form(keep="all", days="90"))
    assert kept.status_code == 303
    assert console.window() is None
    page = console.page(kept.headers["location"]).text
    assert _words(page, "done-notice") == (
        "Saved. Every episode is kept from now on; episodes already removed stay removed."
    )
    assert _words(page, "window-words") == "Every episode is kept until the person is erased."
    assert [e["detail"] for e in console.audit("fleet.history")] == [
        {"history_days": None},
        {"history_days": 90},
    ]


@pytest.mark.parametrize(
    ("fields", "says"),
    [
        (
            {"keep": "days", "days": "0"},
            "0 days cannot be set: the number of days goes from 1 to 36,500",
        ),
        (
            {"keep": "days", "days": "36501"},
            "36501 days cannot be set: the number of days goes from 1 to 36,500",
        ),
        (
            {"keep": "days", "days": "ninety"},
            "Write the number of days as a whole number, from 1 to 36,500.",
        ),
        ({"keep": "days", "days": "2.5"}, "Write the number of days as a whole number"),
        ({"keep": "days", "days": ""}, "Write the number of days as a whole number"),
        ({"days": "30"}, "Choose whether to keep every episode or to remove the older ones."),
    ],
)
def test_a_mistake_comes_back_in_words_and_changes_nothing(
    console: Console, fields: dict[str, str], says: str
) -> None:
    form = console.form(**fields)
    if "keep" not in fields:
        form.pop("keep", None)
    r = console.post(form)
    assert r.status_code == 422, r.text
    assert _words(r.text, "form-errors").startswith("Nothing was changed.")
    assert says in _words(r.text, "error-days")
    if fields.get("days"):
        assert (
            f'value="{html.escape(fields["days"])}"' in r.text.split('id="days"')[1].split(">")[0]
        )
    assert console.window() is None
    assert console.audit("fleet.history") == []


def test_a_form_from_elsewhere_is_refused(console: Console) -> None:
    form = console.form(keep="days", days="30")
    for bad in ({**form, "csrf": ""}, {**form, "csrf": "0" * 64}):
        r = console.post(bad)
        assert r.status_code == 403, r.text
        assert "Request refused" in r.text
    r = console.post(form, headers={"Origin": "https://evil.example"})
    assert r.status_code == 403
    r = console.post(form, headers={"Sec-Fetch-Site": "cross-site"})
    assert r.status_code == 403
    assert console.window() is None


def test_another_fleets_staff_and_robots_neither_see_nor_set_it(
    app: FastAPI, console: Console, make_key: MakeKey
) -> None:
    form = console.form(keep="days", days="30")
    with TestClient(app, raise_server_exceptions=False, follow_redirects=False) as other:
        other.cookies.set("attune_console", make_key("staff", "south"), path="/admin")
        assert other.get("/admin/retention").status_code == 200  # their own fleet's
        seen = other.get(f"/admin/retention?fleet={FLEET}")
        assert seen.status_code == 403
        assert "own fleet" in seen.text
        assert 'id="window-words"' not in seen.text
        # Their own page's token, posted at north's address.
        block = other.get("/admin/retention").text.split('id="window-form"')[1]
        token = re.search(r'name="csrf" value="([^"]+)"', block)
        assert token is not None
        r = other.post(f"/admin/retention?fleet={FLEET}", data={**form, "csrf": token.group(1)})
        assert r.status_code == 403
    with TestClient(app, raise_server_exceptions=False, follow_redirects=False) as robot:
        robot.cookies.set("attune_console", make_key("robot", FLEET), path="/admin")
        r = robot.get(f"/admin/retention?fleet={FLEET}")
        assert r.status_code == 403
        assert "A staff or admin key is needed" in r.text
        assert 'id="window-words"' not in r.text
        # The refusal signed the browser out: the key again, for the form.
        robot.cookies.set("attune_console", make_key("robot", FLEET), path="/admin")
        assert robot.post(f"/admin/retention?fleet={FLEET}", data=form).status_code == 403
    assert console.window() is None


def test_an_admin_chooses_the_fleet(app: FastAPI, console: Console, make_key: MakeKey) -> None:
    with TestClient(app, raise_server_exceptions=False, follow_redirects=False) as admin:
        admin.cookies.set("attune_console", make_key("admin", "default"), path="/admin")
        page = admin.get(f"/admin/retention?fleet={FLEET}")
        assert page.status_code == 200
        assert '<option value="north" selected>north</option>' in page.text
        assert f'action="/admin/retention?fleet={FLEET}" class="window-form"' in page.text
        block = page.text.split('id="window-form"')[1]
        token = re.search(r'name="csrf" value="([^"]+)"', block)
        assert token is not None
        r = admin.post(
            f"/admin/retention?fleet={FLEET}",
            data={"csrf": token.group(1), "keep": "days", "days": "400"},
        )
        assert r.status_code == 303, r.text
        # A fleet without people yet: its window is set all the same, and a run says so.
        page = admin.get("/admin/retention?fleet=empty")
        assert page.status_code == 200
        r = admin.post(
            "/admin/retention?fleet=empty",
            data={"csrf": token.group(1), "keep": "days", "days": "7"},
        )
        assert r.status_code == 303, r.text
        retention.run(app.state.db, app.state.ctx, fleet="empty")
        assert _words(admin.get("/admin/retention?fleet=empty").text, "last-run").endswith(
            ": the fleet had no one's history to go through."
        )
    assert console.window() == 400
    (entry,) = console.audit("fleet.history")
    assert entry["actor"]["role"] == "admin"


def test_the_last_clean_up_and_each_persons_history_from(app: FastAPI, console: Console) -> None:
    assert console.post(console.form(keep="days", days="30")).status_code == 303
    for path in ("/admin/users/lin", "/admin/users/lin/episodes", "/admin/users/lin/details"):
        assert 'id="history-from"' not in console.page(path).text  # nothing removed yet
    later = dt.datetime.now(dt.UTC) + dt.timedelta(days=31)
    done = retention.run(app.state.db, app.state.ctx, now=later)
    assert done.episodes_removed == 3  # the three closed ones; the open one stays
    run = console.audit("fleet.retention")[0]
    page = console.page().text
    stats = console.api.get("/v1/users/lin/stats").json()
    kept_from = dt.datetime.fromisoformat(stats["history_from"])
    zone = zoneinfo.ZoneInfo(ZONE)
    ran = dt.datetime.fromisoformat(run["at"]).astimezone(zone)
    assert _words(page, "last-run") == (
        f"Last clean-up: {ran:%Y-%m-%d %H:%M}: it went through 1 person's history and removed "
        "3 episodes older than 30 days."
    )
    for path in (
        "/admin/users/lin",
        "/admin/users/lin/episodes",
        "/admin/users/lin/details",
        "/admin/users/lin/why",
    ):
        head = _words(console.page(path).text, "history-from")
        assert head == (
            f"History kept from {kept_from.astimezone(zone):%Y-%m-%d %H:%M}: older episodes "
            "were removed by the fleet's clean-up, and what the robot learned from them is "
            "kept (how long history is kept)."
        ), path
    # A run that finds nothing more to remove says so.
    retention.run(app.state.db, app.state.ctx, now=later)
    assert _words(console.page().text, "last-run").endswith(
        ": it went through 1 person's history and found no episode older than 30 days."
    )


def test_the_services_own_time_is_said(
    settings: Settings, empty_tables: None, make_key: MakeKey
) -> None:
    timed = settings.model_copy(update={"retention_at": DailyTime(dt.time(3, 30), "Europe/London")})
    app = create_app(timed)  # its lifespan is not started: no schedule runs here
    try:
        client = TestClient(app, follow_redirects=False)
        client.cookies.set("attune_console", make_key("staff", FLEET), path="/admin")
        page = client.get("/admin/retention")
        assert page.status_code == 200
        block = page.text.split('id="window-form"')[1]
        token = re.search(r'name="csrf" value="([^"]+)"', block)
        assert token is not None
        r = client.post(
            "/admin/retention", data={"csrf": token.group(1), "keep": "days", "days": "1"}
        )
        assert r.status_code == 303
        assert _words(client.get(r.headers["location"]).text, "window-words") == (
            "Episodes older than 1 day are removed each day at 03:30 (Europe/London); what the "
            "robot learned from them is kept."
        )
    finally:
        app.state.db.dispose()
