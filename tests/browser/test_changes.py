"""What changed in what people want, in headless Chromium: a fleet's staff member opens "What
changed this week", reads the change in words, follows it to the person's page (which lists
it too) and to the episodes that showed it; staff of another fleet are refused."""

from __future__ import annotations

import httpx
import pytest
from playwright.sync_api import Page, expect

from app.services.auth import create_key
from tests.support.episodes import play
from tests.support.people import person

from .conftest import Shot, Site, sign_in
from .test_mission import _check_basics

pytestmark = [pytest.mark.browser, pytest.mark.xdist_group("browser")]


def _fleet(site: Site, fleet: str) -> tuple[str, str]:
    """A staff key of ``fleet`` and another fleet's; ``fleet``'s Mrs. Chen took tea in the
    afternoon while stretching, day after day, then turned it down for coffee."""
    with site.database.transaction() as session:
        _, staff = create_key(session, role="staff", fleet=fleet, name="day-shift")
        _, robot = create_key(session, role="robot", fleet=fleet, name=f"{fleet}-robot")
        _, stranger = create_key(session, role="staff", fleet=f"{fleet}-else", name="other")
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {robot}"}
    ) as api:
        assert api.put("/v1/users/chen", json={"display_name": "Mrs. Chen"}).status_code == 201
        for i in range(11):
            need = ("ProvideDrink", "tea") if i < 8 else ("ProvideDrink", "coffee")
            play(
                api,
                "chen",
                f"chen-{i}",
                person(need=need),
                situation="stretching",
                occurred_at=f"2026-11-{20 + i}T15:10:00+08:00",
            )
    return staff, stranger


def test_staff_read_what_changed_and_follow_it(
    page: Page, site: Site, shot: Shot, viewport: str
) -> None:
    fleet = f"changes-{viewport}"
    staff, stranger = _fleet(site, fleet)
    sign_in(page, site, staff, "/admin/changes")
    expect(page.locator("h1")).to_have_text("What changed this week")
    item = page.locator("#changes li.wish-change")
    expect(item).to_have_count(1)
    expect(item.locator(".change-words")).to_contain_text("Since 28 November, Mrs. Chen")
    expect(item.locator(".change-words")).to_contain_text("tea")
    expect(item.locator(".change-words")).to_contain_text("in the afternoon, while stretching")
    _check_basics(page)
    shot(page, "changes")

    # To the person's page, at that box: it lists the change too.
    item.locator("a.who").click()
    page.wait_for_url("**/admin/users/chen?*")
    expect(page.locator("#changes-card")).to_contain_text("Since 28 November, Mrs. Chen")
    expect(page.locator("#evidence-title")).to_contain_text("stretching")
    _check_basics(page)
    shot(page, "profile-changes")

    # To an episode that showed it.
    page.locator("#changes-card a.evidence-link").first.click()
    page.wait_for_url("**/admin/users/chen/episodes?*")
    expect(page.locator("#episodes details.episode").first).to_contain_text("#9")

    # Staff of another fleet see none of it.
    other = page.context.browser.new_context().new_page()  # type: ignore[union-attr]
    try:
        sign_in(other, site, stranger, f"/admin/changes?fleet={fleet}")
        expect(other.locator("h1")).to_have_text("Not allowed")
        expect(other.locator("#changes")).to_have_count(0)
    finally:
        other.context.close()
