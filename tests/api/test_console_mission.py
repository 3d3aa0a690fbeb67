"""The console's mission page and its form, without a browser, on both engines: the mission in
force in plain words, the versions with what each changed, the form's preview and confirmation,
mistakes shown next to the field with what was typed, a double submit made once, staleness."""

from __future__ import annotations

import html
import re
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from tests.support.episodes import start
from tests.support.fixtures import MakeKey

FLEET = "north"
SERVICES = (
    "ProvideDrink: tea, coffee, water\nBriefInformation: news, weather, stocks\n"
    "ArrangeSchedule: today_agenda, next_meeting, set_reminder"
)
COCOA = SERVICES.replace("water", "water, cocoa")


class Console:
    """A browser signed in with a staff key of ``north``; its robot made one user with an open
    episode."""

    def __init__(self, client: TestClient, robot: TestClient) -> None:
        self.client, self.robot = client, robot

    def page(self, path: str = "/admin/mission") -> httpx.Response:
        r: httpx.Response = self.client.get(path)
        assert r.status_code == 200, r.text
        return r

    def form(self, path: str = "/admin/mission", **fields: str) -> dict[str, str]:
        """The page's hidden fields (CSRF token, change id, base version) and ``fields``."""
        text = self.page(path).text
        hidden = dict(
            re.findall(
                r'<input type="hidden" name="(\w+)" value="([^"]*)"',
                text.split('id="mission-form"')[1],
            )
        )
        return {**{k: html.unescape(v) for k, v in hidden.items()}, **fields}

    def post(self, form: dict[str, str], path: str = "/admin/mission") -> httpx.Response:
        r: httpx.Response = self.client.post(path, data=form)
        return r


def errors(r: httpx.Response) -> dict[str, str]:
    return {
        k: html.unescape(v)
        for k, v in re.findall(r'<p class="field-error" id="error-(\w+)">(.*?)</p>', r.text)
    }


def changes(r: httpx.Response, where: str) -> list[str]:
    block = r.text.split(f'id="{where}"')[1].split("</ul>")[0]
    return [html.unescape(t) for t in re.findall(r'<li class="change[^"]*">(.*?)</li>', block)]


@pytest.fixture
def console(app: FastAPI, make_key: MakeKey) -> Iterator[Console]:
    robot = TestClient(app, headers={"Authorization": f"Bearer {make_key('robot', FLEET)}"})
    client = TestClient(app, raise_server_exceptions=False, follow_redirects=False)
    client.cookies.set("attune_console", make_key("staff", FLEET), path="/admin")
    with robot, client:
        start(robot, "lin", "e1", situation="working")
        yield Console(client, robot)


def test_the_page_shows_the_mission_in_plain_words(console: Console) -> None:
    text = console.page().text
    assert 'id="current-version">1<' in text
    assert (
        '<tr data-service="ProvideDrink"><th scope="row">ProvideDrink</th>'
        '<td class="choices">tea, coffee, water</td>' in text
    )
    assert re.search(r'data-situation="busy">busy <span class="badge"[^>]*>do not disturb', text)
    assert not re.search(r'data-situation="working">working <span', text)
    assert '<th scope="row">evening</th><td>18:00</td><td>06:00</td>' in text
    assert "The fleet's first mission." in text
    assert 'href="/admin/mission' in text
    assert 'aria-current="page">Mission' in text
    # The form holds the mission as staff write it.
    assert (
        f'<textarea id="services" name="services" rows="4" spellcheck="false" '
        f'aria-describedby="hint-services">{SERVICES}</textarea>' in text
    )
    assert 'name="time_slots"' in text
    assert "morning 06:00-11:00\nnoon 11:00-14:00" in text


def test_preview_then_apply_adds_a_choice(console: Console) -> None:
    form = console.form(services=COCOA)
    assert len(form["change_id"]) == 32
    assert form["base_version"] == "1"
    preview = console.post(form)
    assert preview.status_code == 200, preview.text
    assert changes(preview, "preview-changes") == ["New choice for ProvideDrink: cocoa."]
    impact = re.sub(r"\s+", " ", preview.text.split('id="preview-impact">')[1].split("</p>")[0])
    assert "<b>1</b> person&#39;s model moves" in impact
    assert "<b>1</b> conversation in progress will be interrupted" in impact
    assert console.robot.get("/v1/mission").json()["version"] == 1  # nothing stored yet
    # The confirmation form carries what was typed.
    confirm = dict(
        re.findall(
            r'<input type="hidden" name="(\w+)" value="([^"]*)"',
            preview.text.split('id="confirm-form"')[1].split("</form>")[0],
        )
    )
    confirm = {k: html.unescape(v) for k, v in confirm.items()}
    assert confirm["step"] == "confirm"
    assert confirm["services"] == COCOA
    done = console.post(confirm)
    assert done.status_code == 303, done.text
    assert done.headers["location"] == f"/admin/mission?fleet={FLEET}&done=2"
    again = console.post(confirm)  # a double submit is one change
    assert again.headers["location"] == done.headers["location"]
    mission = console.robot.get("/v1/mission").json()
    assert mission["version"] == 2
    assert mission["services"][0]["details"] == ["tea", "coffee", "water", "cocoa"]
    page = console.page(done.headers["location"])
    notice = re.sub(r"\s+", " ", page.text.split('id="done-notice"')[1].split("</div>")[0])
    assert "Version <b>2</b> is now in force" in notice
    assert "1 person&#39;s model moved to it; 1 conversation in progress was interrupted" in notice
    assert 'id="current-version">2<' in page.text
    assert changes(page, "history") == ["New choice for ProvideDrink: cocoa."]
    # The user's page offers the new choice.
    user = console.page("/admin/users/lin")
    assert '<td class="choices">tea, coffee, water, cocoa</td>' in user.text
    assert 'id="offers-version">2<' in user.text


def test_renames_and_other_changes_in_words(console: Console) -> None:
    form = console.form(
        services=SERVICES.replace("tea", "chai").replace("ArrangeSchedule", "Agenda"),
        situations="arriving, working, resting, busy",
        do_not_disturb="busy, resting",
        time_slots="morning 06:00-11:00\nnoon 11:00-14:00\nafternoon 14:00-19:00\n"
        "night 19:00-06:00",
        renames="tea -> chai\nArrangeSchedule -> Agenda\nevening -> night",
        gamma="0.8",
    )
    preview = console.post(form)
    assert preview.status_code == 200, preview.text
    assert changes(preview, "preview-changes") == [
        "Service ArrangeSchedule renamed Agenda.",
        "Choice of ProvideDrink renamed: tea → chai.",
        "New situation: resting.",
        "Situation removed: stretching.",
        "Do not disturb now in: busy, resting.",
        "Time slot renamed: evening → night.",
        "Hours of afternoon: 14:00–18:00 become 14:00–19:00.",
        "Hours of night: 18:00–06:00 become 19:00–06:00.",
        "The discount (advanced settings) changed from 0.9 to 0.8.",
    ]
    confirm = {**form, "step": "confirm"}
    assert console.post(confirm).status_code == 303
    model = console.robot.get("/v1/users/lin/model").json()
    assert model["mission_version"] == 2
    assert {c["time_slot"] for c in model["contexts"]} == {"morning", "noon", "afternoon", "night"}


@pytest.mark.parametrize(
    ("fields", "where", "message"),
    [
        (
            {"services": "ProvideDrink tea"},
            "services",
            "Line 1, 'ProvideDrink tea': write a service and its choices as "
            "'ProvideDrink: tea, coffee, water'.",
        ),
        (
            {"services": "ProvideDrink: tea, hot water"},
            "services",
            "ProvideDrink, choice 2: 'hot water' is not a valid name",
        ),
        (
            {"services": "ProvideDrink: tea, tea"},
            "services",
            "ProvideDrink, choice 2: the name 'tea' is used twice.",
        ),
        (
            {"do_not_disturb": "asleep"},
            "do_not_disturb",
            "Do-not-disturb situation 1: 'asleep' is not one of the situations",
        ),
        (
            {"time_slots": "day 06:00-20:00"},
            "time_slots",
            "No slot covers 00:00; the slots must cover the whole day.",
        ),
        (
            {"time_slots": "day from six"},
            "time_slots",
            "'day from six': write a time slot as its name and its local hours",
        ),
        (
            {"renames": "chai -> tea"},
            "renames",
            "'chai -> tea': the mission in force has no service, choice, situation or time slot "
            "named 'chai'.",
        ),
        (
            {"renames": "tea -> cocoa"},
            "renames",
            "Rename of tea: 'cocoa' is not a choice of ProvideDrink in the new mission",
        ),
        ({"gamma": "1"}, "gamma", "The discount must be in [0, 1), got 1.0."),
        ({"reward_negative": "2"}, "reward_negative", "Must be below 0, got 2.0."),
        ({"reward_query": "a lot"}, "reward_query", "'a lot' is not a number."),
    ],
)
@pytest.mark.parametrize("step", ["preview", "confirm"])
def test_mistakes_come_back_next_to_the_field(
    console: Console, fields: dict[str, str], where: str, message: str, step: str
) -> None:
    form = console.form(**fields, step=step)
    r = console.post(form)
    assert r.status_code == 422, r.text
    found = errors(r)
    assert list(found) == [where], found
    assert found[where].startswith(message), found[where]
    assert 'id="form-errors" data-status="422"' in r.text
    for name, value in fields.items():  # the form keeps what was typed
        assert html.escape(value) in r.text, name
    assert (
        f'id="error-{where}"' in r.text.split(f'name="{where}"')[1].split("</div>")[0]
        or where.startswith("reward")
        or where == "gamma"
    )
    assert console.robot.get("/v1/mission").json()["version"] == 1


def test_stale_and_reused_forms(console: Console) -> None:
    first = console.form(services=COCOA, step="confirm")
    stale = console.form(services=SERVICES.replace("news", "sports"), step="confirm")
    assert console.post(first).status_code == 303
    r = console.post(stale)  # made from version 1, which is no longer in force
    assert r.status_code == 409
    assert "changed meanwhile (it is now version 2)" in r.text
    assert "sports" in r.text  # kept
    # The same change id with another mission: refused, with a fresh id to try again.
    reused = {**first, "services": SERVICES, "base_version": "2"}
    r = console.post(reused)
    assert r.status_code == 409
    assert "already used for another change" in r.text
    assert first["change_id"] not in r.text
    # Nothing typed differs from the mission in force: nothing to apply.
    r = console.post(console.form())
    assert r.status_code == 200
    assert "Nothing would change" in r.text
    assert 'id="apply"' not in r.text
    assert console.robot.get("/v1/mission").json()["version"] == 2


def test_the_form_needs_the_pages_token(console: Console) -> None:
    form = console.form(services=COCOA, step="confirm")
    for bad in ({**form, "csrf": ""}, {**form, "csrf": "0" * 64}):
        r = console.post(bad)
        assert r.status_code == 403
    r = console.client.post("/admin/mission", data=form, headers={"origin": "http://evil.example"})
    assert r.status_code == 403
    assert console.robot.get("/v1/mission").json()["version"] == 1


def test_admins_choose_the_fleet(app: FastAPI, make_key: MakeKey, console: Console) -> None:
    client = TestClient(app, raise_server_exceptions=False, follow_redirects=False)
    client.cookies.set("attune_console", make_key("admin"), path="/admin")
    with client:
        r = client.get(f"/admin/mission?fleet={FLEET}")
        assert r.status_code == 200
        assert f'<option value="{FLEET}" selected>' in r.text
        assert '<label for="fleet-choice">Fleet</label>' in r.text
        text = r.text.split('id="mission-form"')[1]
        form: dict[str, Any] = dict(
            re.findall(r'<input type="hidden" name="(\w+)" value="([^"]*)"', text)
        )
        form.update(services=COCOA, step="confirm")
        done = client.post(f"/admin/mission?fleet={FLEET}", data=form)
        assert done.status_code == 303
        assert done.headers["location"] == f"/admin/mission?fleet={FLEET}&done=2"
    assert console.robot.get("/v1/mission").json()["version"] == 2
    # Staff naming another fleet: refused, as the API refuses them.
    r = console.client.get("/admin/mission?fleet=default")
    assert r.status_code == 403
    assert 'data-status="403"' in r.text


def test_a_fleet_without_users_previews_its_change_as_version_2(
    app: FastAPI, make_key: MakeKey
) -> None:
    # Version 1 is the default the fleet has until then; the change stores it, then version 2.
    client = TestClient(app, raise_server_exceptions=False, follow_redirects=False)
    client.cookies.set("attune_console", make_key("staff", "south"), path="/admin")
    with client:
        console = Console(client, client)
        form = console.form(services=COCOA)
        assert form["base_version"] == "0"  # nothing stored yet
        preview = console.post(form)
        assert preview.status_code == 200, preview.text
        assert "Apply version 2" in preview.text
        confirm = dict(
            re.findall(
                r'<input type="hidden" name="(\w+)" value="([^"]*)"',
                preview.text.split('id="confirm-form"')[1].split("</form>")[0],
            )
        )
        done = console.post({k: html.unescape(v) for k, v in confirm.items()})
        assert done.status_code == 303, done.text
        assert done.headers["location"].endswith("&done=2")
