"""The mission page in headless Chromium: a fleet's staff member changes the mission through
the form (no JSON), sees the new version and what changed, and finds the new choice on a
person's page."""

from __future__ import annotations

import httpx
import pytest
from playwright.sync_api import Page, expect

from app.services.auth import create_key

from .conftest import Shot, Site, sign_in
from .people import Person, meet

pytestmark = [pytest.mark.browser, pytest.mark.xdist_group("browser")]

# Every form control needs a name a screen reader can say: a <label for>, a wrapping label,
# aria-label or aria-labelledby. Hidden inputs aside.
UNLABELLED = """() => [...document.querySelectorAll("input, textarea, select")]
  .filter(el => el.type !== "hidden")
  .filter(el => !(el.labels && el.labels.length) && !el.getAttribute("aria-label")
                && !el.getAttribute("aria-labelledby"))
  .map(el => el.name || el.id || el.outerHTML)"""
NAMELESS_BUTTONS = """() => [...document.querySelectorAll("button, a.button")]
  .filter(el => !el.textContent.trim() && !el.getAttribute("aria-label"))
  .map(el => el.outerHTML)"""


def _check_basics(page: Page) -> None:
    assert page.evaluate(UNLABELLED) == []
    assert page.evaluate(NAMELESS_BUTTONS) == []
    assert page.get_attribute("html", "lang") == "en"
    expect(page.locator("h1")).to_have_count(1)
    described = page.locator("[aria-describedby]").evaluate_all(
        "els => els.flatMap(el => el.getAttribute('aria-describedby').split(' '))"
        ".filter(id => !document.getElementById(id))"
    )
    assert described == []  # every hint or error a field points to exists


def _fleet(site: Site, fleet: str) -> tuple[str, str]:
    """A staff key and a robot key of ``fleet``, whose robot made user ``ada`` with some history
    and one conversation in progress."""
    with site.database.transaction() as session:
        _, staff = create_key(session, role="staff", fleet=fleet, name=f"{fleet}-staff")
        _, robot = create_key(session, role="robot", fleet=fleet, name=f"{fleet}-robot")
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {robot}"}
    ) as api:
        assert api.put("/v1/users/ada", json={"display_name": "Ada"}).status_code == 201
        meet(api, "ada", Person({("morning", "working"): ("ProvideDrink", "tea")}), 6, prefix="ada")
        r = api.post(
            "/v1/users/ada/episodes",
            json={
                "event_id": "ada-open",
                "situation": "working",
                "robot_id": "robot7",
                "occurred_at": "2026-11-20T09:30:00+08:00",
                "initiator": "robot",
            },
        )
        assert r.status_code == 201, r.text
    return staff, robot


def test_staff_add_a_choice_and_see_it_on_a_persons_page(
    page: Page, site: Site, shot: Shot, viewport: str
) -> None:
    fleet = f"mission-{viewport}"
    staff, robot = _fleet(site, fleet)
    sign_in(page, site, staff, "/admin/mission")
    assert page.url.endswith("/admin/mission"), page.url
    expect(page.locator("#mission-fleet")).to_contain_text(fleet)
    expect(page.locator("#current-version")).to_have_text("1")
    expect(page.locator("#offers-table tr[data-service='ProvideDrink'] .choices")).to_have_text(
        "tea, coffee, water"
    )
    expect(page.locator("#situations li[data-situation='busy']")).to_contain_text("do not disturb")
    _check_basics(page)
    shot(page, "mission")

    # A mistake comes back next to the field, with what was typed.
    typed = page.input_value("#services")
    page.fill("#services", typed + "\nBriefing news")
    page.click("#preview-button")
    expect(page.locator("#error-services")).to_contain_text("Line 4, 'Briefing news'")
    assert page.input_value("#services") == typed + "\nBriefing news"
    expect(page.locator("#services")).to_have_attribute("aria-invalid", "true")
    _check_basics(page)
    shot(page, "mission-error")

    page.fill("#services", typed.replace("water", "water, cocoa"))
    page.click("#preview-button")
    expect(page.locator("#preview-changes")).to_have_text("New choice for ProvideDrink: cocoa.")
    expect(page.locator("#preview-impact")).to_contain_text("1 person's model moves")
    expect(page.locator("#preview-impact")).to_contain_text("1 conversation in progress")
    _check_basics(page)
    shot(page, "mission-preview")
    page.click("#apply")
    page.wait_for_url(f"**/admin/mission?fleet={fleet}&done=2")
    expect(page.locator("#done-notice")).to_contain_text("Version 2 is now in force")
    expect(page.locator("#current-version")).to_have_text("2")
    expect(page.locator("#offers-table tr[data-service='ProvideDrink'] .choices")).to_have_text(
        "tea, coffee, water, cocoa"
    )
    latest = page.locator("#history li.version[data-version='2']")
    expect(latest).to_contain_text("New choice for ProvideDrink: cocoa.")
    expect(latest).to_contain_text("in force")
    expect(page.locator("#history li.version[data-version='1']")).to_contain_text(
        "The fleet's first mission."
    )
    shot(page, "mission-changed")
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {robot}"}
    ) as api:
        mission = api.get("/v1/mission").json()
        assert mission["version"] == 2
        assert mission["services"][0]["details"] == ["tea", "coffee", "water", "cocoa"]
        assert api.get("/v1/users/ada/model").json()["mission_version"] == 2

    page.goto(f"{site.url}/admin/users/ada")
    expect(page.locator("#offers tr[data-service='ProvideDrink'] .choices")).to_have_text(
        "tea, coffee, water, cocoa"
    )
    expect(page.locator("#offers-version")).to_have_text("2")
    shot(page, "user-offers")


def test_robot_keys_cannot_reach_the_mission_page(site: Site) -> None:
    with httpx.Client(
        base_url=site.url,
        cookies={"attune_console": site.robot_key},
        timeout=30,
        follow_redirects=False,
    ) as console:
        r = console.get("/admin/mission")
        assert r.status_code == 403
        assert "ProvideDrink" not in r.text
