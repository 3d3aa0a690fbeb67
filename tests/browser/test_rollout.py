"""Rollout, in headless Chromium: a fleet's staff member starts trying a learner without acting
(a shadow), then starts a rollout of another learner to half of the people from the form (a
mistake comes back in words), sees the two groups and the comparison's sentence as the API gives
them, with its plot once the robots met everyone a few times, finds the group on a person's
profile, and promotes it through the confirmation; staff of another fleet are refused.

With ``ATTUNE_DOCS_SHOTS=1`` the desktop screenshots of the rollout page (once the shadow has
decided) and of the promote confirmation are also written to ``docs/img/console-rollout.png`` and
``docs/img/console-rollout-promote.png`` (docs/console.md shows them)."""

from __future__ import annotations

import datetime as dt
import os
import time
from typing import Any

import httpx
import pytest
from playwright.sync_api import Page, expect

from app.console import views
from app.services.auth import create_key
from tests.support import people
from tests.support.episodes import play

from .conftest import DOCS_IMG, Shot, Site, sign_in
from .test_mission import _check_basics

pytestmark = [pytest.mark.browser, pytest.mark.xdist_group("browser")]

TEA = ("ProvideDrink", "tea")
PEOPLE = 24
ROUNDS = 4  # encounters of each person once the rollout started
LABEL = "HRI τ=0.005"
WAIT_S = 60.0  # a bound on how long the people's moves, or the shadow's pass, may take
DOCS = {"rollout": "console-rollout.png", "promote": "console-rollout-promote.png"}


def _fleet(site: Site, fleet: str) -> tuple[str, str, str]:
    """A staff key of ``fleet`` (named ``day-shift``), its robot's key and another fleet's staff
    key; the robots met each of ``PEOPLE`` people once, under HRI."""
    with site.database.transaction() as session:
        _, staff = create_key(session, role="staff", fleet=fleet, name="day-shift")
        _, robot = create_key(session, role="robot", fleet=fleet, name=f"{fleet}-robot")
        _, stranger = create_key(session, role="staff", fleet=f"{fleet}-else", name="other")
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {robot}"}
    ) as api:
        for i in range(PEOPLE):
            user = f"r{i:02d}"
            r = api.put(f"/v1/users/{user}", json={"learner": {"algorithm": "hri"}})
            assert r.status_code == 201, r.text
            play(api, user, f"{user}-e0", people.person(need=TEA))
    return staff, robot, stranger


def _rollout(site: Site, key: str, fleet: str) -> dict[str, Any]:
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {key}"}
    ) as api:
        r = api.get(f"/v1/admin/fleets/{fleet}/rollout")
        assert r.status_code == 200, r.text
        found: dict[str, Any] = r.json()
        return found


def _moved(site: Site, key: str, fleet: str) -> dict[str, Any]:
    """The rollout once everyone it moves has moved (the service does it in the background)."""
    deadline = time.monotonic() + WAIT_S
    while (found := _rollout(site, key, fleet)).get("moving"):
        assert time.monotonic() < deadline, f"people still moving after {WAIT_S} s"
        time.sleep(0.1)
    return found


def _shadowed(site: Site, key: str, fleet: str) -> dict[str, Any]:
    """The fleet's shadow once it has decided and made its estimate (bounded)."""
    deadline = time.monotonic() + WAIT_S
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {key}"}
    ) as api:
        while True:
            r = api.get(f"/v1/admin/fleets/{fleet}/shadow")
            assert r.status_code == 200, r.text
            found: dict[str, Any] = r.json()
            if found["decisions"] and found["estimate"] is not None:
                return found
            assert time.monotonic() < deadline, f"the shadow has not decided after {WAIT_S} s"
            time.sleep(0.5)


def _docs(viewport: str) -> bool:
    return viewport == "desktop" and os.environ.get("ATTUNE_DOCS_SHOTS") == "1"


def _docs_shot(page: Page, viewport: str, name: str) -> None:
    if _docs(viewport):
        page.screenshot(path=str(DOCS_IMG / DOCS[name]), full_page=True)


def test_staff_roll_a_learner_out_read_the_groups_and_promote_it(
    page: Page, site: Site, shot: Shot, viewport: str
) -> None:
    fleet = f"rollout-{viewport}"
    staff, robot, stranger = _fleet(site, fleet)
    sign_in(page, site, staff, "/admin/rollout")
    assert page.url.endswith("/admin/rollout"), page.url
    expect(page.locator("h1")).to_have_text("Try another learner, safely")
    expect(page.locator("#rollout-fleet")).to_contain_text(fleet)
    expect(page.locator("#nav-rollout")).to_have_attribute("aria-current", "page")
    expect(page.locator("#rollout-now")).to_have_count(0)
    _check_basics(page)

    # First a learner tried without acting: DTS, beside the robots, for everyone.
    page.check("#shadow-pick-dts")
    expect(page.locator("#shadow-percent")).to_have_value("100")
    page.click("#start-shadow")
    page.wait_for_url(f"**/admin/rollout?fleet={fleet}&done=shadow-started")
    expect(page.locator("#shadow-summary")).to_have_text(
        "DTS has not decided yet: it decides once an episode has ended."
    )
    expect(page.locator("#shadow-status")).to_contain_text("(started by day-shift), for 100%")
    expect(page.locator("#stop-shadow")).to_be_visible()
    expect(page.locator("#shadow-form")).to_have_count(0)

    # Nothing chosen: said in words, nothing started.
    page.click("#start-rollout")
    expect(page.locator("#rollout-error-learner")).to_have_text("Choose the learner to try.")
    expect(page.locator("#rollout-errors")).to_have_attribute("data-status", "422")
    _check_basics(page)

    # The learner in plain words, half of the people.
    page.check("#rollout-pick-hri-less")
    page.fill("#rollout-percent", "50")
    shot(page, "rollout-form")
    page.click("#start-rollout")
    page.wait_for_url(f"**/admin/rollout?fleet={fleet}&done=started")
    expect(page.locator("#done-notice")).to_contain_text("The rollout has started.")
    look = _moved(site, staff, fleet)
    assert look["status"] == "running"
    assert look["candidate"]["label"] == LABEL
    expect(page.locator("#rollout-status")).to_contain_text("by day-shift, for 50% of the people.")

    # The robots meet everyone a few times; the page then compares the two groups.
    now = dt.datetime.now(dt.UTC).isoformat()  # after the shadow started: it estimates them
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {robot}"}
    ) as api:
        for e in range(ROUNDS):
            for i in range(PEOPLE):
                user = f"r{i:02d}"
                play(api, user, f"{user}-r{e}", people.person(need=TEA), occurred_at=now)
    look = _rollout(site, staff, fleet)
    assert look["comparison"]["enough"], look["comparison"]
    page.goto(f"{site.url}/admin/rollout?fleet={fleet}")
    expect(page.locator("#rollout-summary")).to_have_text(look["summary"])
    expect(page.locator("#arm-candidate")).to_have_text(str(look["people"]["candidate"]))
    expect(page.locator("#arm-control")).to_have_text(str(look["people"]["control"]))
    assert look["people"]["candidate"] + look["people"]["control"] == PEOPLE
    expect(page.locator("#rollout-plot svg")).to_be_visible()
    expect(page.locator("#rollout-plot .plot-row")).to_have_count(1)
    expect(page.locator("#rollout-moving")).to_have_count(0)
    _check_basics(page)
    shot(page, "rollout")
    if _docs(viewport):  # with what the shadow decided meanwhile (its pass runs every 30 s)
        shadow = _shadowed(site, staff, fleet)
        page.reload()
        agreement, estimate = views.shadow_words(shadow)
        expect(page.locator("#shadow-summary")).to_have_text(agreement)
        expect(page.locator("#shadow-estimate")).to_have_text(estimate or "")
        _docs_shot(page, viewport, "rollout")

    # A person's profile says which group they are in.
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {staff}"}
    ) as api:
        arm = api.get("/v1/users/r00/profile").json()["rollout"]["arm"]
    page.goto(f"{site.url}/admin/users/r00?fleet={fleet}")
    expect(page.locator("#rollout-arm")).to_contain_text(
        f"In the rollout of {LABEL}: "
        + ("served by the candidate since " if arm == "candidate" else "keeps the current learner.")
    )
    page.click("#rollout-link")
    page.wait_for_url(f"**/admin/rollout?fleet={fleet}")

    # Promoted through its confirmation.
    page.click("#promote")
    page.wait_for_url(f"**/admin/rollout/promote?fleet={fleet}")
    expect(page.locator("h1")).to_have_text(f"Promote {LABEL}?")
    expect(page.locator("#confirm-text")).to_contain_text(
        f"who keep the current learner move to {LABEL} now"
    )
    _check_basics(page)
    shot(page, "rollout-promote")
    _docs_shot(page, viewport, "promote")
    page.click("#confirm-promote")
    page.wait_for_url(f"**/admin/rollout?fleet={fleet}&done=promoted")
    expect(page.locator("#done-notice")).to_contain_text("Promoted.")
    expect(page.locator("#rollout-status")).to_contain_text("Promoted on ")
    expect(page.locator("#rollout-status")).to_contain_text(f"by day-shift: {LABEL} serves")
    expect(page.locator("#promote")).to_have_count(0)
    expect(page.locator("#rollout-form")).to_be_visible()
    _check_basics(page)
    assert _moved(site, staff, fleet)["status"] == "promoted"

    # Staff of another fleet see none of it.
    other = page.context.browser.new_context().new_page()  # type: ignore[union-attr]
    try:
        sign_in(other, site, stranger, f"/admin/rollout?fleet={fleet}")
        expect(other.locator("h1")).to_have_text("Not allowed")
        expect(other.locator("#rollout-now")).to_have_count(0)
    finally:
        other.context.close()
