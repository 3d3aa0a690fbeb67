"""The admin console, page by page, in headless Chromium against a live service: every number a
page shows is checked against what the v1 API returns for the same user."""

from __future__ import annotations

import json
import re
from typing import Any

import httpx
import pytest
from playwright.sync_api import Page, expect

from .conftest import VIEWPORTS, ZONE, Shot, Site, sign_in
from .people import (
    action_label,
    count,
    expected_cell,
    measure,
    one,
    pct,
    state_label,
    two,
)

pytestmark = [pytest.mark.browser, pytest.mark.xdist_group("browser")]


# The engineers' terms: on the Details tab and under "Details for engineers" only.
ENGINEERS_WORDS = ("τ", "ΔQ", "n′", "I1", "I2", "I3", "model version", "P(", "λ")
ENGINEERS_NAMES = (
    "OBSERVE",
    "ENGAGED",
    "REQUEST",
    "TYPE_KNOWN",
    "DETAIL_KNOWN",
    "infer_type",
    "infer_detail",
    "query_type",
    "query_detail",
    "initiate",
)


def _no_engineers_terms(text: str, where: str) -> None:
    found = [w for w in ENGINEERS_WORDS if w.lower() in text.lower()]
    found += [w for w in ENGINEERS_NAMES if re.search(rf"\b{w}\b", text)]
    assert found == [], (where, found)


def _text(page: Page, selector: str) -> str:
    return page.locator(selector).inner_text().strip()


class TestSignIn:
    def test_robot_and_unknown_keys_are_refused(self, page: Page, site: Site, shot: Shot) -> None:
        answer = sign_in(page, site, site.robot_key)
        assert answer is not None
        assert answer.status == 403
        expect(page.locator("#login-error")).to_contain_text("robot key")
        assert page.context.cookies() == []
        shot(page, "login-refused-robot")

        answer = sign_in(page, site, "att_not-a-key-of-this-service")
        assert answer is not None
        assert answer.status == 401
        expect(page.locator("#login-error")).to_contain_text("not known")
        assert page.context.cookies() == []

        # Nothing is reachable without signing in: the login form, then back to the page.
        page.goto(site.url + "/admin/users/lin")
        assert re.search(r"/admin/login\?next=/admin/users/lin$", page.url), page.url
        shot(page, "login")

    def test_the_admin_key_is_kept_for_the_browser_session_only(
        self, page: Page, site: Site
    ) -> None:
        answer = sign_in(page, site, site.admin_key, "/admin/users/lin")
        assert answer is not None
        assert answer.status == 303
        assert page.url.endswith("/admin/users/lin")  # back where the person was heading
        (cookie,) = page.context.cookies()
        assert cookie["name"] == "attune_console"
        assert cookie["httpOnly"] is True
        assert cookie["sameSite"] == "Strict"
        assert cookie["expires"] == -1  # no Max-Age: ends with the browser session
        assert cookie["path"] == "/admin"
        response = page.goto(site.url + "/admin/users")
        assert response is not None
        assert "script-src 'self'" in response.headers["content-security-policy"]
        assert response.headers["x-frame-options"] == "DENY"
        assert site.admin_key not in page.content()  # the page shows a token, never the key

    def test_a_revoked_key_stops_at_once_and_sign_out_forgets_the_key(
        self, page: Page, site: Site, shot: Shot
    ) -> None:
        key = site.create_key("admin", name="revoke-me")
        sign_in(page, site, key)
        site.revoke_key(_text(page, ".who").removeprefix("key ").strip())
        response = page.reload()
        assert response is not None
        assert response.status == 401
        expect(page.locator("#error")).to_contain_text("revoked")
        assert page.context.cookies() == []
        shot(page, "revoked")

        sign_in(page, site, site.admin_key)
        page.click("#logout")
        page.wait_for_url("**/admin/login?signed_out=true")
        expect(page.locator("#signed-out")).to_be_visible()
        assert page.context.cookies() == []
        page.goto(site.url + "/admin/users")
        assert "/admin/login" in page.url


class TestUsers:
    def test_search_and_pages(self, admin_page: Page, site: Site, shot: Shot) -> None:
        page = admin_page
        shot(page, "users")
        page.fill("#search", "PAGER")  # any case, in the id or the display name
        page.click("form.search button[type=submit]")
        page.wait_for_url("**q=PAGER**")
        expect(page.locator("#users-count")).to_contain_text("30 users matching")
        ids = page.locator("#users tbody tr").evaluate_all(
            "rows => rows.map(r => r.dataset.userId)"
        )
        assert ids == [f"pager-{i:02d}" for i in range(25)]
        page.click("#next-page")
        page.wait_for_url("**page=2**")
        ids = page.locator("#users tbody tr").evaluate_all(
            "rows => rows.map(r => r.dataset.userId)"
        )
        assert ids == [f"pager-{i:02d}" for i in range(25, 30)]
        expect(page.locator("#prev-page")).to_be_visible()
        expect(page.locator("#users tr[data-user-id='pager-29'] .learner")).to_have_text("rmax")

        page.fill("#search", "mrs. l")  # Mrs. Lin, by display name
        page.click("form.search button[type=submit]")
        page.wait_for_url("**q=mrs.**")
        row = page.locator("#users tbody tr")
        expect(row).to_have_count(1)
        user = site.get("/v1/users/lin")
        recent = site.get("/v1/users/lin/stats", last=100)
        assert row.get_attribute("data-user-id") == "lin"
        assert _text(page, "#users .episodes") == str(user["episodes"]) == "60"
        assert _text(page, "#users .success") == pct(recent["success_rate"])
        assert _text(page, "#users .learner") == "hri"
        # Last activity: when the service received it, in the fleet's time zone, said.
        assert re.fullmatch(rf"\d{{4}}-\d\d-\d\d \d\d:\d\d {ZONE}", _text(page, "#users .activity"))
        expect(page.locator("#users thead")).to_contain_text("received")
        shot(page, "users-search")


class TestUserModel:
    def test_heatmap_and_metrics_show_the_api_numbers(
        self, admin_page: Page, site: Site, shot: Shot, viewport: str
    ) -> None:
        page = admin_page
        for user_id in ("lin", "chen"):
            page.goto(f"{site.url}/admin/users/{user_id}")
            page.click("#tab-details")  # the engineers' views
            page.wait_for_url(f"**/admin/users/{user_id}/details?fleet=default")
            model = site.get(f"/v1/users/{user_id}/model")
            assert _text(page, "#model-version") == str(model["version"])
            assert _text(page, "#learner").startswith("hri τ=" if user_id == "lin" else "dts λ=")
            cells = page.locator("#heatmap td.cell")
            expect(cells).to_have_count(len(model["contexts"]))
            for context in model["contexts"]:
                cell = page.locator(
                    f"#heatmap td[data-time-slot='{context['time_slot']}']"
                    f"[data-situation='{context['situation']}']"
                )
                want = expected_cell(context)
                assert cell.locator(".p-init").inner_text() == want["p-init"]
                assert cell.locator(".n").inner_text().split()[0] == want["episodes"]
                if want.get("expect") == "no mission yet":
                    assert cell.locator(".expect").inner_text() == "no mission yet"
                    continue
                assert cell.locator(".service").inner_text() == want["service"]
                assert cell.locator(".p-ask").inner_text() == want["p-ask"]
                if "detail" in want:
                    assert cell.locator(".detail").inner_text() == want["detail"]
                    assert cell.locator(".p-guess").inner_text() == want["p-guess"]
                else:
                    expect(cell.locator(".p-guess")).to_have_count(0)

            for column, params in (("recent", {"last": 100}), ("all", {})):
                stats = site.get(f"/v1/users/{user_id}/stats", **params)
                shown = {
                    row.get_attribute("data-metric"): row.locator(f"td.{column}").inner_text()
                    for row in page.locator("#stats tbody tr").all()
                }
                assert shown == {
                    "episodes": str(stats["episodes"]),
                    "missions": str(stats["missions"]),
                    "interaction_rate": pct(stats["interaction_rate"]),
                    "success_rate": pct(stats["success_rate"]),
                    "queries_per_mission": two(stats["queries_per_mission"]),
                    "total_reward": one(stats["total_reward"]),
                }, (user_id, column)
            expect(page.locator("#reward-chart[data-ready=yes] canvas")).to_have_count(1)
            # Whole episodes on the x axis, and the curve's end said without hovering.
            for width in (VIEWPORTS[viewport]["width"], 420):  # narrow: fewer ticks, still whole
                page.set_viewport_size({"width": width, "height": 800})
                page.wait_for_function(
                    f"() => document.querySelector('#reward-chart canvas')"
                    f".getBoundingClientRect().width < {width}"
                )
                ticks = (page.get_attribute("#reward-chart", "data-x-ticks") or "").split()
                assert ticks, width
                assert all(t.isdigit() for t in ticks), ticks
            page.set_viewport_size(VIEWPORTS[viewport])
            stats = site.get(f"/v1/users/{user_id}/stats")
            expect(page.locator("#reward-caption")).to_contain_text(
                f"Cumulative reward: {one(stats['total_reward'])} after {stats['episodes']} "
                "episodes"
            )
            shot(page, f"details-{user_id}")

    def test_why_table_shows_the_api_numbers(
        self, admin_page: Page, site: Site, shot: Shot
    ) -> None:
        page = admin_page
        page.goto(f"{site.url}/admin/users/lin/why")
        latest = site.get("/v1/users/lin/episodes", limit=1)["items"][0]["context"]
        assert page.locator("#time-slot").input_value() == latest["time_slot"]
        assert page.locator("#situation").input_value() == latest["situation"]

        page.select_option("#time-slot", "afternoon")  # the selects reload the page
        page.wait_for_url("**time_slot=afternoon**")
        page.select_option("#situation", "stretching")
        page.wait_for_url("**situation=stretching**")
        model = site.get("/v1/users/lin/model", time_slot="afternoon", situation="stretching")
        (context,) = model["contexts"]
        # For staff, in words: what drives the decision and how this learner chooses; the
        # numbers stay folded under "Details for engineers" until opened.
        episodes = sum(a["visits"] for a in context["states"][0]["actions"])
        expect(page.locator("#drivers .answers")).to_contain_text(
            f"Mrs. Lin's own answers in {episodes} episodes here"
        )
        expect(page.locator("#learner-words")).to_contain_text("sets aside old answers")
        _no_engineers_terms(page.locator("main").inner_text(), "why")
        expect(page.locator("#why")).not_to_be_visible()
        shot(page, "why-words")
        page.click("#why-engineers summary")
        expect(page.locator("#why")).to_be_visible()
        expect(page.locator("#p-explained")).to_contain_text("exp(Pref/τ)")
        rows = 0
        for state in context["states"]:
            for belief in state["actions"]:
                row = page.locator(
                    f"#why tr[data-state='{state_label(state)}']"
                    f"[data-action='{action_label(belief['action'])}']"
                )
                expect(row).to_have_count(1)
                shown = [
                    row.locator(f"td.{c}").inner_text().strip()
                    for c in ("q", "visits", "kept", "t", "m", "p")
                ]
                assert shown == [
                    two(belief["q"]),
                    count(belief["visits"]),
                    count(belief["kept_visits"]),
                    str(belief["since_last"]),
                    measure(belief["measure"]),
                    pct(belief["p"]),
                ], (state, belief)
                rows += 1
        expect(page.locator("#why tbody tr")).to_have_count(rows)

        # "What it did last time here" is the latest episode in that context.
        episodes = site.get("/v1/users/lin/episodes", limit=100)["items"]
        last = next(
            e
            for e in episodes
            if e["context"] == {"time_slot": "afternoon", "situation": "stretching"}
        )
        expect(page.locator("#last-decision a")).to_have_text(f"episode #{last['index']}")
        expect(page.locator("#why-legend")).to_contain_text("temporal measure")
        shot(page, "why")


class TestEpisodes:
    def test_list_pages_and_traces_expand(self, admin_page: Page, site: Site, shot: Shot) -> None:
        page = admin_page
        page.goto(f"{site.url}/admin/users/lin/episodes")
        listed = site.get("/v1/users/lin/episodes", limit=25)["items"]
        ids = page.locator("details.episode").evaluate_all(
            "rows => rows.map(r => r.dataset.episodeId)"
        )
        assert ids == [e["episode_id"] for e in listed]

        # The first human-initiated episode with feedback makes the richest trace.
        first = page.locator("details.episode").first
        first.locator("summary").click()
        body = first.locator(".trace-body")
        expect(body).to_have_count(1)
        trace = site.get(f"/v1/episodes/{listed[0]['episode_id']}")
        # Step by step in words for staff: one line per decision and later feedback.
        steps = body.locator("li.step")
        expect(steps).to_have_count(len(trace["decisions"]) + len(trace["feedback"]))
        for step, decision in zip(steps.all(), trace["decisions"], strict=False):
            assert step.inner_text().startswith("The robot "), step.inner_text()
            assert step.get_attribute("data-decision-id") == decision["decision_id"]
        expect(body.locator("tr.decision").first).not_to_be_visible()
        shot(page, "episodes-words")
        # Every trace opened: no engineers' term on the page staff read.
        for other in page.locator("details.episode").all()[1:]:
            other.locator("summary.ep-row").click()
            expect(other.locator(".trace-body")).to_have_count(1)
        _no_engineers_terms(page.locator("main").inner_text(), "episodes, every trace open")
        for other in page.locator("details.episode").all()[1:]:
            other.locator("summary.ep-row").click()  # closed again, for the screenshot
        body.locator("details.engineers summary").click()
        decisions = body.locator("tr.decision")
        expect(decisions).to_have_count(len(trace["decisions"]))
        for row, decision in zip(decisions.all(), trace["decisions"], strict=True):
            assert row.get_attribute("data-decision-id") == decision["decision_id"]
            assert action_label(decision["action"]) in row.locator("td.action").inner_text()
            assert row.locator("td.reward").inner_text() == one(decision["reward"])
            chosen = next(
                p["p"] for p in decision["probabilities"] if p["action"] == decision["action"]
            )
            assert row.locator("td.p").inner_text() == pct(chosen)
            chain = row.locator("td.chain").inner_text()
            for step in decision["chain"]:
                assert f"{action_label(step['action'])} ({pct(step['p'])})" in chain
        expect(body.locator("tr.feedback")).to_have_count(len(trace["feedback"]))
        shot(page, "episodes")

        page.click("#older")
        page.wait_for_url("**before=**")
        indices = page.locator("details.episode .idx").all_inner_texts()
        assert indices[0] == "#35"
        assert indices[-1] == "#11"
        page.click("#newer")
        page.wait_for_url("**/episodes?fleet=default&per_page=25")
        assert page.locator("details.episode .idx").first.inner_text() == "#60"
        page.fill("#goto", "10")
        page.click("#episodes-card form button[type=submit]")
        page.wait_for_url("**at=10**")
        assert page.locator("details.episode .idx").all_inner_texts() == [
            f"#{i}" for i in range(10, 0, -1)
        ]


class TestAdminActions:
    def test_export_downloads_the_model_document(self, admin_page: Page, site: Site) -> None:
        page = admin_page
        page.goto(f"{site.url}/admin/users/chen")
        with page.expect_download() as download:
            page.click("#export")
        assert download.value.suggested_filename == "attune-model-chen.json"
        with open(download.value.path(), encoding="utf-8") as f:
            doc = json.load(f)
        assert doc == site.get("/v1/users/chen/model/export")

    def test_export_everything_downloads_the_persons_export(
        self, admin_page: Page, site: Site
    ) -> None:
        page = admin_page
        page.goto(f"{site.url}/admin/users/chen")
        with page.expect_download() as download:
            page.click("#export-everything")
        assert download.value.suggested_filename == "attune-person-default-chen.json"
        with open(download.value.path(), encoding="utf-8") as f:
            doc = json.load(f)
        assert doc["format"] == "attune.subject"
        assert doc["person"]["user_id"] == "chen"
        assert len(doc["episodes"]) == doc["episode_count"] == doc["person"]["episodes"]
        assert any(v["what"] == "console.profile" for v in doc["views"])

    def test_reset_asks_first_then_forgets_the_model(
        self, admin_page: Page, site: Site, shot: Shot, viewport: str
    ) -> None:
        page, user_id = admin_page, f"reset-{viewport}"
        before = site.get(f"/v1/users/{user_id}/model")
        assert any(
            a["visits"] for c in before["contexts"] for s in c["states"] for a in s["actions"]
        )
        page.goto(f"{site.url}/admin/users/{user_id}/details")
        page.click("#reset")
        expect(page.locator("#confirm")).to_contain_text("history (12 episodes) is kept")
        shot(page, "confirm-reset")
        page.click("#cancel")
        page.wait_for_url(f"**/admin/users/{user_id}?fleet=default")
        assert site.get(f"/v1/users/{user_id}/model")["version"] == before["version"]

        page.click("#reset")
        page.click("#confirm-reset")
        page.wait_for_url(f"**/admin/users/{user_id}/details?fleet=default&done=reset")
        expect(page.locator("#reset-notice")).to_be_visible()
        after = site.get(f"/v1/users/{user_id}/model")
        assert after["version"] == before["version"] + 1
        assert not any(
            a["visits"] for c in after["contexts"] for s in c["states"] for a in s["actions"]
        )
        assert after["episodes"] == 12  # the history is kept
        assert _text(page, "#model-version") == str(after["version"])
        expect(page.locator("#heatmap .expect.none")).to_have_count(16)
        shot(page, "user-after-reset")

    def test_delete_asks_first_then_removes_the_user(
        self, admin_page: Page, site: Site, shot: Shot, viewport: str
    ) -> None:
        page, user_id = admin_page, f"gone-{viewport}"
        page.goto(f"{site.url}/admin/users/{user_id}")
        page.click("#delete")
        expect(page.locator("#confirm")).to_contain_text("cannot be undone")
        shot(page, "confirm-delete")
        page.click("#confirm-delete")
        page.wait_for_url(f"**/admin/users?deleted={user_id}")
        expect(page.locator("#deleted-notice")).to_contain_text(user_id)
        assert site.api.get(f"/v1/users/{user_id}").status_code == 404
        response = page.goto(f"{site.url}/admin/users/{user_id}")
        assert response is not None
        assert response.status == 404
        shot(page, "not-found")


def _console(site: Site, key: str | None) -> httpx.Client:
    cookies = {"attune_console": key} if key else {}
    return httpx.Client(base_url=site.url, cookies=cookies, timeout=30, follow_redirects=False)


def _token(html: str) -> str:
    found = re.search(r'name="csrf" value="([0-9a-f]{64})"', html)
    assert found, "no CSRF token in the page"
    return found.group(1)


class TestProtection:
    """Without a browser: what a forged or foreign request gets."""

    def test_state_changes_need_the_pages_token_and_origin(self, site: Site) -> None:
        version = site.get("/v1/users/lin/model")["version"]
        with _console(site, site.admin_key) as console:
            confirm = console.get("/admin/users/lin/reset")
            assert confirm.status_code == 200
            token = _token(confirm.text)
            assert site.admin_key not in confirm.text
            form = {"content-type": "application/x-www-form-urlencoded"}
            for body, headers in (
                ("", form),
                ("csrf=" + "0" * 64, form),
                (f"csrf={token}", {**form, "origin": "http://evil.example"}),
                (f"csrf={token}", {**form, "sec-fetch-site": "cross-site"}),
            ):
                r = console.post("/admin/users/lin/reset", content=body, headers=headers)
                assert r.status_code == 403, (body, headers, r.status_code)
                assert "text/html" in r.headers["content-type"]
            r = console.post(
                "/admin/users/lin/delete",
                content=f"csrf={token}",
                headers={**form, "origin": "http://evil.example"},
            )
            assert r.status_code == 403
        assert site.get("/v1/users/lin/model")["version"] == version
        assert site.api.get("/v1/users/lin").status_code == 200

    def test_cookies_other_than_an_admin_key_get_pages_not_data(self, site: Site) -> None:
        for key, status in ((site.robot_key, 403), ("att_bogus", 401), (None, 303)):
            with _console(site, key) as console:
                r = console.get("/admin/users/lin")
                assert r.status_code == status, (key, r.status_code)
                if status == 303:
                    assert r.headers["location"] == "/admin/login?next=/admin/users/lin"
                else:
                    assert "Mrs. Lin" not in r.text
                    assert "attune_console=" in r.headers.get("set-cookie", "")  # forgotten

    def test_the_console_is_not_part_of_the_api_schema(self, site: Site) -> None:
        paths: dict[str, Any] = site.get("/openapi.json")["paths"]
        assert not [p for p in paths if p.startswith("/admin")]
