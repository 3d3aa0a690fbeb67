"""A person's profile in headless Chromium: the grid says in words what the person wants and what
the robot will do; a box opens its evidence (by click and by keyboard); staff correct it through
the form (prefers, avoid, quiet) and lift a correction; and the robot's next decision through the
v1 API follows a prefers correction."""

from __future__ import annotations

import re
from typing import Any

import httpx
import pytest
from playwright.sync_api import Page, expect

from .conftest import LIN_NEEDS, Shot, Site
from .people import HOURS, Person, meet
from .test_mission import _check_basics

pytestmark = [pytest.mark.browser, pytest.mark.xdist_group("browser")]

ROBOT_WILL = (
    "Offers it without asking",
    "Offers help and asks what first",
    "Waits to be asked",
    "Stays away",
)


def _person(site: Site, user_id: str) -> None:
    """``user_id``, Mrs. Lin's needs, 40 episodes (made through the API by the fleet's robot)."""
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {site.robot_key}"}
    ) as robot:
        if robot.get(f"/v1/users/{user_id}").status_code == 200:
            return
        r = robot.put(f"/v1/users/{user_id}", json={"display_name": "Mrs. Wu"})
        assert r.status_code == 201, r.text
        meet(robot, user_id, Person(dict(LIN_NEEDS)), 40, prefix=user_id)


def _words(wanted: dict[str, Any]) -> str:
    """What a box says is wanted: {"service": "ProvideDrink", "detail": "today_agenda"} ->
    "Provide drink (today agenda)"."""
    service = re.sub(r"(?<=[a-z])(?=[A-Z])", " ", wanted["service"])
    service = service[0] + service[1:].lower()
    detail = wanted.get("detail")
    return service + (f" ({detail.replace('_', ' ')})" if detail else "")


def _cell(page: Page, time_slot: str, situation: str) -> Any:
    return page.locator(f"#profile td[data-time-slot='{time_slot}'][data-situation='{situation}']")


def _next_decision(
    site: Site, user_id: str, event_id: str, time_slot: str, situation: str
) -> dict[str, Any]:
    """The robot meets the person in (time slot, situation): what the API tells it to do."""
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {site.robot_key}"}
    ) as robot:
        r = robot.post(
            f"/v1/users/{user_id}/episodes",
            json={
                "event_id": event_id,
                "situation": situation,
                "robot_id": "robot7",
                "occurred_at": f"2026-11-29T{HOURS[time_slot]:02d}:15:00+08:00",
                "initiator": "robot",
            },
        )
        assert r.status_code == 201, r.text
        episode: dict[str, Any] = r.json()
        assert episode["context"] == {"time_slot": time_slot, "situation": situation}
        decision: dict[str, Any] = episode["decision"]
        return decision


def test_the_grid_says_in_words_and_a_box_opens_its_evidence(
    admin_page: Page, site: Site, shot: Shot, viewport: str
) -> None:
    page, user_id = admin_page, f"wu-{viewport}"
    _person(site, user_id)
    page.goto(f"{site.url}/admin/users/{user_id}")
    profile = site.get(f"/v1/users/{user_id}/profile")
    cells = page.locator("#profile td.pcell")
    expect(cells).to_have_count(len(profile["contexts"]))
    for context in profile["contexts"]:
        cell = _cell(page, context["time_slot"], context["situation"])
        assert cell.get_attribute("data-certainty") == context["certainty"]
        assert context["certainty"] in (cell.get_attribute("class") or "")
        text = cell.inner_text()
        assert any(words in text for words in ROBOT_WILL), text
        if context["certainty"] == "unknown" and context["wants"] is None:
            assert "Not enough to say yet" in text
        elif context["wants"] is not None:
            expect(cell.locator(".wants")).to_have_text(_words(context["wants"]))
    # How sure shows in the look: a confident box is solid, a tentative one is not.
    looks = {
        c: page.locator(f"#profile td.pcell.sure-{c} a").first
        for c in ("confident", "tentative", "unknown")
    }
    styles = {
        c: loc.evaluate(
            "a => [getComputedStyle(a).backgroundColor, getComputedStyle(a).borderTopStyle]"
        )
        for c, loc in looks.items()
        if loc.count()
    }
    if "confident" in styles and "tentative" in styles:
        assert styles["confident"] != styles["tentative"]
        assert styles["tentative"][1] == "dashed"
    # A box under the pointer, or with the keyboard's focus, is said as a sentence.
    for context in profile["contexts"][:3]:
        link = _cell(page, context["time_slot"], context["situation"]).locator("a")
        link.hover()
        expect(page.locator("#cell-summary")).to_have_text(context["summary"])
    last = profile["contexts"][-1]
    page.mouse.move(0, 0)  # off the grid: focusing may scroll another box under the pointer
    _cell(page, last["time_slot"], last["situation"]).locator("a").focus()
    expect(page.locator("#cell-summary")).to_have_text(last["summary"])
    head = page.locator("#episode-count").inner_text()
    expected = f"{profile['episodes']} episodes"
    if profile["open_episodes"]:
        expected += f" ({profile['open_episodes']} open)"
    assert head == expected
    assert sum(c["episodes"] for c in profile["contexts"]) == profile["episodes"]
    page_text = page.locator("main").inner_text()
    for word in ("τ", "ΔQ", "n′", "I1", "I2", "I3", "model version"):
        assert word not in page_text
    _check_basics(page)
    shot(page, "profile")

    # A click opens a box's evidence.
    _cell(page, "afternoon", "stretching").locator("a").click()
    page.wait_for_url("**time_slot=afternoon&situation=stretching**")
    context = next(
        c
        for c in profile["contexts"]
        if (c["time_slot"], c["situation"]) == ("afternoon", "stretching")
    )
    evidence = page.locator("#evidence")
    expect(evidence).to_be_visible()
    expect(evidence.locator("#summary")).to_have_text(context["summary"])
    e = context["evidence"]
    expect(evidence.locator("dd[data-fact=accepted]")).to_contain_text(str(e["accepted"]))
    expect(evidence.locator("dd[data-fact=refused]")).to_contain_text(str(e["refused"]))
    expect(evidence.locator("dd[data-fact=asked_for]")).to_contain_text(str(e["asked_for"]))
    expect(evidence.locator("dd[data-fact=answered]")).to_contain_text(str(e["answered"]))
    expect(evidence.locator("dd[data-fact=agree]")).to_have_text(
        f"{e['support']} of the last {e['recent']} answer{'' if e['recent'] == 1 else 's'} agree"
        if e["recent"]
        else "no answer yet"
    )
    assert re.fullmatch(
        r"2026-11-\d\d 15:\d\d \(robot's time of the event, Asia/Shanghai\)",
        evidence.locator("dd[data-fact=last_seen]").inner_text(),
    )
    expect(evidence).to_be_focused()
    _check_basics(page)
    shot(page, "profile-evidence")

    # The keyboard opens another: Tab to the box, Enter.
    link = _cell(page, "morning", "arriving").locator("a")
    link.focus()
    page.keyboard.press("Enter")
    page.wait_for_url("**time_slot=morning&situation=arriving**")
    expect(page.locator("#evidence-title")).to_have_text("Morning, arriving")


def _correct(
    page: Page,
    time_slot: str,
    situation: str,
    kind: str,
    service: str = "",
    detail: str = "",
    note: str = "",
) -> None:
    _cell(page, time_slot, situation).locator("a").click()
    page.wait_for_url(f"**time_slot={time_slot}&situation={situation}**")
    page.check(f"#kind-{kind}")
    if service:
        page.select_option("#c-service", service)
        page.select_option("#c-detail", detail)
    if note:
        page.fill("#c-note", note)
    page.click("#correction-submit")
    page.wait_for_url("**done=corrected**")
    expect(page.locator("#done-notice")).to_contain_text("The correction is saved")


def test_staff_correct_and_lift_and_the_robot_follows(
    admin_page: Page, site: Site, shot: Shot, viewport: str
) -> None:
    page, user_id = admin_page, f"wu-{viewport}"
    _person(site, user_id)
    page.goto(f"{site.url}/admin/users/{user_id}")

    # A prefers correction where the person has shown no wish: the robot now offers it.
    _correct(
        page,
        "evening",
        "working",
        "prefers",
        "ProvideDrink",
        "coffee",
        note="Her daughter says she has coffee in the evening.",
    )
    # Quiet disables the service and choice.
    page.check("#kind-quiet")
    expect(page.locator("#c-service")).to_be_disabled()
    page.check("#kind-prefers")
    expect(page.locator("#c-service")).to_be_enabled()
    cell = _cell(page, "evening", "working")
    expect(cell.locator(".wants")).to_have_text("Provide drink (coffee)")
    expect(cell).to_contain_text("set by staff")
    rows = page.locator("#corrections tbody tr")
    expect(rows).to_have_count(1)
    expect(rows.first.locator(".what .words")).to_have_text("Prefers Provide drink (coffee)")
    expect(rows.first.locator(".note")).to_have_text(
        "Her daughter says she has coffee in the evening."
    )
    expect(rows.first.locator(".status")).to_have_text("In force")
    (made,) = site.get(f"/v1/users/{user_id}/corrections")["items"]
    assert (made["kind"], made["service"], made["detail"]) == ("prefers", "ProvideDrink", "coffee")
    assert made["author"] == page.locator(".who").inner_text().removeprefix("key ").strip()
    decision = _next_decision(site, user_id, f"after-prefers-{viewport}", "evening", "working")
    assert decision["action"]["kind"] == "initiate", decision
    _check_basics(page)
    shot(page, "profile-corrected")

    # Avoid and quiet, in other boxes.
    _correct(
        page, "morning", "arriving", "avoid", "BriefInformation", "", note="The news upsets her."
    )
    _correct(page, "noon", "stretching", "quiet")
    expect(rows).to_have_count(3)
    expect(page.locator("#corrections .what .words")).to_have_text(
        [
            "Prefers Provide drink (coffee)",
            "Do not offer Brief information",
            "Quiet: the robot does not offer help",
        ]
    )
    expect(_cell(page, "noon", "stretching")).to_contain_text("set by staff")
    # A box set by staff says so, not that the person's answers agree.
    expect(_cell(page, "evening", "working").locator(".sure")).to_have_text("set by staff")
    # The whole table fits the page, Status and Lift included, on a tablet too.
    wrap = page.locator("#corrections-card .table-wrap")
    assert wrap.evaluate("w => w.scrollWidth <= w.clientWidth"), viewport
    box = page.locator("#corrections button.lift").first.bounding_box()
    assert box is not None
    assert page.viewport_size is not None
    assert box["x"] + box["width"] <= page.viewport_size["width"]
    author = rows.first.locator(".author").inner_text()
    assert author.startswith("console-tests"), author  # the key's name, not its id
    decision = _next_decision(site, user_id, f"after-quiet-{viewport}", "noon", "stretching")
    assert decision["action"]["kind"] == "pass", decision
    shot(page, "profile-corrections")

    # Lift the quiet one with its button.
    quiet = page.locator("#corrections tbody tr", has_text="Quiet")
    quiet.get_by_role("button", name=re.compile("^Lift")).click()
    page.wait_for_url("**done=lifted**")
    expect(page.locator("#done-notice")).to_contain_text("lifted")
    expect(page.locator("#corrections tbody tr")).to_have_count(2)
    statuses = {
        c["kind"]: c["status"] for c in site.get(f"/v1/users/{user_id}/corrections")["items"]
    }
    assert statuses == {"prefers": "in_force", "avoid": "in_force", "quiet": "lifted"}
    _check_basics(page)


def test_a_mistake_comes_back_in_words(admin_page: Page, site: Site, viewport: str) -> None:
    page, user_id = admin_page, f"wu-{viewport}"
    _person(site, user_id)
    page.goto(f"{site.url}/admin/users/{user_id}?time_slot=afternoon&situation=arriving")
    page.check("#kind-avoid")
    page.select_option("#c-service", "")
    page.fill("#c-note", "kept as typed")
    page.click("#correction-submit")
    expect(page.locator("#correction-error")).to_have_text(
        "Choose what the robot should not offer."
    )
    assert page.input_value("#c-note") == "kept as typed"
    assert page.is_checked("#kind-avoid")
