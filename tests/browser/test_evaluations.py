"""What if, in headless Chromium: a fleet's staff member starts an evaluation of other learners
from the form, watches the page follow it to the end, reads what it found in words beside what
the robots earn now (the same verdicts as the API's), opens a person's "What if" from the table,
and finds the evaluation in the fleet's list; staff of another fleet are refused.

With ``ATTUNE_DOCS_SHOTS=1`` the desktop screenshot of an evaluation's page is also written to
``docs/img/console-whatif.png`` and the person's tab to ``docs/img/console-person-whatif.png``
(docs/console.md shows them)."""

from __future__ import annotations

import os
import random
import re

import httpx
import pytest
from playwright.sync_api import Page, expect

from app.services.auth import create_key
from tests.support import people
from tests.support.episodes import play

from .conftest import DOCS_IMG, Shot, Site, sign_in
from .test_mission import _check_basics

pytestmark = [pytest.mark.browser, pytest.mark.xdist_group("browser")]

NEEDS = (("ProvideDrink", "tea"), ("BriefInformation", "news"), ("ProvideDrink", "coffee"))
PEOPLE = ("lin", "ada", "bo", "cy", "dee")
EPISODES = 20  # each person's; Mrs. Lin ten more
WAIT_MS = 120_000  # a bound on how long the page may take to show what the evaluation found
DOCS = {"evaluation": "console-whatif.png", "person-whatif": "console-person-whatif.png"}


def _fleet(site: Site, fleet: str) -> tuple[str, str]:
    """A staff key of ``fleet`` (named ``day-shift``) and another fleet's staff key; ``fleet``'s
    robots met five people twenty times each (Mrs. Lin thirty), under HRI."""
    with site.database.transaction() as session:
        _, staff = create_key(session, role="staff", fleet=fleet, name="day-shift")
        _, robot = create_key(session, role="robot", fleet=fleet, name=f"{fleet}-robot")
        _, stranger = create_key(session, role="staff", fleet=f"{fleet}-else", name="other")
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {robot}"}
    ) as api:
        for user in PEOPLE:
            body = {"display_name": "Mrs. Lin"} if user == "lin" else {}
            r = api.put(f"/v1/users/{user}", json={**body, "learner": {"algorithm": "hri"}})
            assert r.status_code == 201, r.text
        for e in range(EPISODES + 10):
            for p, user in enumerate(PEOPLE):
                if e >= EPISODES and user != "lin":
                    continue
                rng = random.Random(p * 100 + e)
                answer = people.person(need=NEEDS[p % 3], rng=rng, yes=0.8, asks=0.6, precise=0.5)
                play(api, user, f"{user}-e{e}", answer)
    return staff, stranger


def _docs_shot(page: Page, viewport: str, name: str) -> None:
    if viewport == "desktop" and os.environ.get("ATTUNE_DOCS_SHOTS") == "1":
        page.screenshot(path=str(DOCS_IMG / DOCS[name]), full_page=True)


def test_staff_start_an_evaluation_and_read_what_it_found(
    page: Page, site: Site, shot: Shot, viewport: str
) -> None:
    fleet = f"whatif-{viewport}"
    staff, stranger = _fleet(site, fleet)
    sign_in(page, site, staff, "/admin/evaluations")
    assert page.url.endswith("/admin/evaluations"), page.url
    expect(page.locator("h1")).to_have_text("What if the robots used another learner?")
    expect(page.locator("#evaluations-fleet")).to_contain_text(fleet)
    expect(page.locator("#no-evaluations")).to_have_text("No evaluation of this fleet yet.")
    expect(page.locator("#nav-evaluations")).to_have_attribute("aria-current", "page")
    _check_basics(page)

    # Nothing chosen: said in words, nothing started.
    page.click("#start-evaluation")
    expect(page.locator("#error-candidates")).to_have_text(
        "Choose at least one learner to compare with what the robots do now."
    )
    _check_basics(page)

    # Two of the plain-language choices, and the robots' own learner under "other learners".
    page.check("#pick-dts")
    page.check("#pick-hri-less")
    page.click("#advanced summary")
    page.fill("#other", "hri")
    shot(page, "evaluations-form")
    page.click("#start-evaluation")
    page.wait_for_url(f"**/admin/evaluations/ev_*?fleet={fleet}")
    expect(page.locator("#evaluation-title")).to_have_text(
        "What if the robots used DTS, HRI τ=0.005 or HRI?"
    )
    expect(page.locator("#evaluation-about")).to_contain_text("by day-shift")
    evaluation_id = page.url.split("/evaluations/")[1].split("?")[0]

    # The page follows it (waiting, running with how many people are done) and shows what it
    # found once it is done, by itself.
    expect(page.locator("#verdicts")).to_be_visible(timeout=WAIT_MS)
    expect(page.locator("#status-words")).to_contain_text("Done, ")
    with httpx.Client(
        base_url=site.url, timeout=30, headers={"Authorization": f"Bearer {staff}"}
    ) as api:
        r = api.get(
            f"/v1/admin/fleets/{fleet}/evaluations/{evaluation_id}", params={"persons": "false"}
        )
        assert r.status_code == 200, r.text
        result = r.json()["result"]
    shown = page.locator("#verdicts li.verdict")
    expect(shown).to_have_count(len(result["candidates"]))
    for candidate in result["candidates"]:
        item = page.locator(f'#verdicts li[data-candidate="{candidate["key"]}"] .verdict-words')
        if candidate["enough"]:
            expect(item).to_have_text(candidate["verdict"] + ".")
        else:
            expect(item).to_contain_text(f"{candidate['label']}: not enough evidence: ")
    expect(page.locator('#verdicts li[data-candidate="hri"] .verdict-words')).to_contain_text(
        re.compile(
            "HRI would earn about the same as what the robots do now: [+−]0.00 per encounter"
        )
    )
    expect(page.locator("#logged-words")).to_contain_text(
        f"What the robots do now: they earn {result['logged']['value']:.2f} per encounter"
    )
    expect(page.locator("#plot svg")).to_be_visible()
    expect(page.locator("#plot .plot-row")).to_have_count(1 + len(result["candidates"]))
    expect(page.locator("#how")).not_to_have_attribute("open", "")
    expect(page.locator("#persons tbody tr")).to_have_count(len(PEOPLE))
    _check_basics(page)
    shot(page, "evaluation")
    _docs_shot(page, viewport, "evaluation")

    # "How this was estimated", for engineers, opens on demand.
    page.click("#how summary")
    expect(page.locator("#how-table")).to_be_visible()
    expect(page.locator("#how")).to_contain_text("Effective sample size")

    # A person's "What if", from the table.
    page.click('#persons a.person-link:text-is("lin")')
    page.wait_for_url(f"**/admin/users/lin/whatif?fleet={fleet}")
    expect(page.locator("#tab-whatif")).to_have_attribute("aria-current", "page")
    expect(page.locator('#person-verdicts li[data-candidate="hri"]')).to_have_text(
        "For Mrs. Lin, HRI would earn about the same as what the robots do now, as far as Mrs. "
        "Lin's encounters alone can tell: +0.00 per encounter (from 30 of Mrs. Lin's "
        "encounters)."
    )
    expect(page.locator("#person-now")).to_contain_text("(30 encounters counted)")
    expect(page.locator("#looked")).to_contain_text("(a what-if evaluation)")
    _check_basics(page)
    shot(page, "person-whatif")
    _docs_shot(page, viewport, "person-whatif")
    page.click("#fleet-evaluation")
    page.wait_for_url(f"**/admin/evaluations/{evaluation_id}?fleet={fleet}")

    # The fleet's list: the evaluation, done, by whom, with a link to what it found.
    page.click("#nav-evaluations")
    page.wait_for_url(f"**/admin/evaluations?fleet={fleet}")
    row = page.locator(f'#evaluations tr[data-evaluation-id="{evaluation_id}"]')
    expect(row).to_have_attribute("data-status", "done")
    expect(row).to_contain_text("day-shift")
    expect(row.locator("a.read")).to_have_text("Read what it found")
    _check_basics(page)
    shot(page, "evaluations")

    # Staff of another fleet see none of it.
    other = page.context.browser.new_context().new_page()  # type: ignore[union-attr]
    try:
        sign_in(other, site, stranger, f"/admin/evaluations/{evaluation_id}?fleet={fleet}")
        expect(other.locator("h1")).to_have_text("Not allowed")
        expect(other.locator("#verdicts")).to_have_count(0)
    finally:
        other.context.close()


def test_the_list_follows_an_evaluation_and_cancels_it(
    page: Page, site: Site, viewport: str
) -> None:
    """Started, the list shows it under way with a Cancel button; cancelled, it says so."""
    fleet = f"whatif-cancel-{viewport}"
    staff, _ = _fleet(site, fleet)
    sign_in(page, site, staff, "/admin/evaluations")
    for pick in ("#pick-dts", "#pick-hri-less", "#pick-hri-more", "#pick-qlearning", "#pick-rmax"):
        page.check(pick)
    page.click("#start-evaluation")
    page.wait_for_url(f"**/admin/evaluations/ev_*?fleet={fleet}")
    evaluation_id = page.url.split("/evaluations/")[1].split("?")[0]
    page.click("#back-to-list")
    row = page.locator(f'#evaluations tr[data-evaluation-id="{evaluation_id}"]')
    expect(row).to_be_visible()
    if row.locator("button.cancel").count():  # still under way: cancel it from the list
        row.locator("button.cancel").click()
        page.wait_for_url(f"**/admin/evaluations?fleet={fleet}&done=cancelled")
        expect(page.locator("#done-notice")).to_contain_text("Cancelled.")
        row = page.locator(f'#evaluations tr[data-evaluation-id="{evaluation_id}"]')
        # The list follows it to its end: cancelled, or done if it ended first.
        expect(row).to_have_attribute("data-status", re.compile("cancelled|done"), timeout=WAIT_MS)
    else:
        expect(row).to_have_attribute("data-status", "done")
    _check_basics(page)
