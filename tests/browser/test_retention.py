"""How long a fleet keeps its history, in headless Chromium: a fleet's staff member sets the
retention window through the form (a mistake comes back in words), reads it back on the page and
through the API, sees the last clean-up and what it removed, and finds on a person's pages from
which date their history is kept; staff of another fleet are refused."""

from __future__ import annotations

import datetime as dt

import httpx
import pytest
from playwright.sync_api import Page, expect

from app.services import retention
from app.services.auth import create_key
from app.services.context import ServiceContext
from app.settings import Settings

from .conftest import Shot, Site, sign_in
from .people import Person, meet
from .test_mission import _check_basics

pytestmark = [pytest.mark.browser, pytest.mark.xdist_group("browser")]


def _fleet(site: Site, fleet: str) -> tuple[str, str]:
    """A staff key of ``fleet`` (named ``day-shift``) and the key of another fleet's staff;
    ``fleet``'s robot made ``ada`` with a few finished episodes."""
    with site.database.transaction() as session:
        _, staff = create_key(session, role="staff", fleet=fleet, name="day-shift")
        _, robot = create_key(session, role="robot", fleet=fleet, name=f"{fleet}-robot")
        _, stranger = create_key(session, role="staff", fleet=f"{fleet}-elsewhere", name="other")
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {robot}"}
    ) as api:
        assert api.put("/v1/users/ada", json={"display_name": "Ada"}).status_code == 201
        meet(api, "ada", Person({("morning", "working"): ("ProvideDrink", "tea")}), 4, prefix="ada")
    return staff, stranger


def _window(site: Site, key: str, fleet: str) -> int | None:
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {key}"}
    ) as api:
        r = api.get(f"/v1/admin/fleets/{fleet}/history")
        assert r.status_code == 200, r.text
        days: int | None = r.json()["history_days"]
        return days


def test_staff_set_the_window_and_read_it_back(
    page: Page, site: Site, shot: Shot, viewport: str
) -> None:
    fleet = f"retention-{viewport}"
    staff, stranger = _fleet(site, fleet)
    sign_in(page, site, staff, "/admin/retention")
    assert page.url.endswith("/admin/retention"), page.url
    expect(page.locator("#retention-fleet")).to_contain_text(fleet)
    expect(page.locator("#window-words")).to_have_text(
        "Every episode is kept until the person is erased."
    )
    expect(page.locator("#last-run")).to_have_text("No clean-up has run for this fleet yet.")
    expect(page.locator("#keep-all")).to_be_checked()
    _check_basics(page)
    shot(page, "retention-default")

    # A mistake comes back in words, with what was typed; nothing changes.
    page.fill("#days", "0")
    expect(page.locator("#keep-days")).to_be_checked()  # typing a number chose it
    page.click("#save-window")
    expect(page.locator("#error-days")).to_contain_text("0 days cannot be set")
    expect(page.locator("#days")).to_have_value("0")
    expect(page.locator("#days")).to_have_attribute("aria-invalid", "true")
    _check_basics(page)
    assert _window(site, staff, fleet) is None

    # Ninety days, with the keyboard: the choice, then the number, then Save.
    page.focus("#keep-days")
    page.keyboard.press("Space")
    page.fill("#days", "90")
    page.click("#save-window")
    page.wait_for_url(f"**/admin/retention?fleet={fleet}&done=saved")
    expect(page.locator("#done-notice")).to_contain_text(
        "From the next clean-up on, episodes older than 90 days are removed."
    )
    expect(page.locator("#window-words")).to_have_text(
        "Episodes older than 90 days are removed each time the clean-up runs (your operator "
        "schedules it); what the robot learned from them is kept."
    )
    expect(page.locator("#window-set")).to_contain_text("Set to 90 days on ")
    expect(page.locator("#window-set")).to_contain_text("by day-shift.")
    assert _window(site, staff, fleet) == 90  # what the API reads back

    # Read back on a fresh visit: the form holds what is in force.
    page.goto(f"{site.url}/admin/retention")
    expect(page.locator("#keep-days")).to_be_checked()
    expect(page.locator("#days")).to_have_value("90")

    # A clean-up runs (as attune retention run would, some months later): the page says when
    # and what it removed, and Ada's pages from when her history is kept.
    ctx = ServiceContext.from_settings(
        Settings(database_url=site.database.url, _env_file=None)  # type: ignore[call-arg]
    )
    later = dt.datetime.now(dt.UTC) + dt.timedelta(days=91)
    done = retention.run(site.database, ctx, fleet=fleet, now=later)
    assert done.episodes_removed == 4
    page.reload()
    expect(page.locator("#last-run")).to_contain_text("Last clean-up: ")
    expect(page.locator("#last-run-removed")).to_have_text("4")
    expect(page.locator("#last-run")).to_contain_text(
        "it went through 1 person's history and removed 4 episodes older than 90 days."
    )
    _check_basics(page)
    shot(page, "retention")
    page.click("#nav-mission")
    expect(page.locator("#mission-fleet")).to_contain_text(fleet)
    page.goto(f"{site.url}/admin/users/ada")
    expect(page.locator("#history-from")).to_contain_text("History kept from ")
    expect(page.locator("#history-from")).to_contain_text(
        "older episodes were removed by the fleet's clean-up, and what the robot learned from "
        "them is kept"
    )
    shot(page, "profile-history-from")
    page.click("#history-from a")
    page.wait_for_url(f"**/admin/retention?fleet={fleet}")

    # Staff of another fleet see neither the window nor the form.
    stranger_page = page.context.browser.new_context().new_page()  # type: ignore[union-attr]
    try:
        sign_in(stranger_page, site, stranger, f"/admin/retention?fleet={fleet}")
        expect(stranger_page.locator("h1")).to_have_text("Not allowed")
        expect(stranger_page.locator("#window-words")).to_have_count(0)
    finally:
        stranger_page.context.close()
