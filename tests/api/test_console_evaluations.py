"""The console's "What if" pages (``/admin/evaluations``, ``/admin/evaluations/{id}`` and a
person's ``/admin/users/{id}/whatif``), without a browser, on both engines: an evaluation of
candidate learners started from the form through the same service as ``POST
/v1/admin/fleets/{fleet}/evaluations`` (audited there, once; a second press of the same form makes
no second one), another one under way or a mistake said on the form in words, a cancel, the result
in words beside what the robots earn now with its plot and its table per person (each person
named recorded as looked at), the person's own "What if" tab, and the refusals (another fleet's
staff, a robot key, a form from elsewhere)."""

from __future__ import annotations

import html
import random
import re
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select

from app.console import views
from app.db.models import DataView
from app.db.repositories import evaluations as repo
from app.db.types import utcnow
from app.services import evaluation_jobs as jobs
from tests.support import people
from tests.support.episodes import play
from tests.support.fixtures import MakeKey

FLEET = "north"
NEEDS = (("ProvideDrink", "tea"), ("BriefInformation", "news"), ("ProvideDrink", "coffee"))
PEOPLE = ("lin", "ada", "bo", "cy", "dee")
WAIT_S = 120.0  # a bound on how long a test waits for an evaluation of this small fleet


def _text(page: str) -> str:
    """What a reader sees: the tags gone, the spaces folded."""
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", " ", page))).strip()


def _words(page: str, where: str) -> str:
    """The text of the element with id ``where`` (to its first closing tag of that kind)."""
    found = re.search(rf'<(\w+)[^>]* id="{where}"[^>]*>(.*?)</\1>', page, flags=re.S)
    assert found, where
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", "", found.group(2)))).strip()


class Console:
    """A browser signed in with a staff key of ``north`` named night-shift (``api``: the same
    key on the v1 API)."""

    def __init__(
        self, app: FastAPI, client: TestClient, api: TestClient, robot: TestClient
    ) -> None:
        self.app, self.client, self.api, self.robot = app, client, api, robot

    def page(self, path: str = "/admin/evaluations") -> httpx.Response:
        r: httpx.Response = self.client.get(path)
        assert r.status_code == 200, r.text
        return r

    def form(self, **fields: str) -> dict[str, str]:
        """The start form's hidden fields, as a fresh page gives them, with ``fields``."""
        block = self.page().text.split('id="evaluation-form"')[1].split("</form>")[0]
        hidden = dict(re.findall(r'<input type="hidden" name="(\w+)" value="([^"]*)"', block))
        return {**{k: html.unescape(v) for k, v in hidden.items()}, **fields}

    def post(self, form: dict[str, str], path: str = "/admin/evaluations") -> httpx.Response:
        r: httpx.Response = self.client.post(path, data=form)
        return r

    def evaluations(self) -> list[dict[str, Any]]:
        r = self.api.get(f"/v1/admin/fleets/{FLEET}/evaluations")
        assert r.status_code == 200, r.text
        items: list[dict[str, Any]] = r.json()["items"]
        return items

    def audit(self, action: str) -> list[dict[str, Any]]:
        items = self.api.get("/v1/admin/audit", params={"limit": 100}).json()["items"]
        return [e for e in items if e["action"] == action]

    def looks(self) -> list[tuple[str, str]]:
        """(what, via) of every look recorded at north's people."""
        with self.app.state.db.transaction(write=False) as session:
            rows = session.execute(
                select(DataView.what, DataView.via).where(DataView.fleet == FLEET)
            ).all()
        return [(str(w), str(v)) for w, v in rows]

    def wait(self, location: str) -> str:
        """The evaluation's page once it has ended (bounded), following it as the page does:
        its progress fragment, until it says it ended."""
        progress = location.replace("?", "/progress?", 1)
        deadline = time.monotonic() + WAIT_S
        while 'data-active="true"' in self.page(progress).text:
            assert time.monotonic() < deadline, f"still under way after {WAIT_S} s"
            time.sleep(0.05)
        return self.page(location).text


def _fill(robot: TestClient, episodes: int) -> None:
    """Five people who met north's robots ``episodes`` times each (Lin ten more times)."""
    for user in PEOPLE:
        body = {"display_name": "Mrs. Lin"} if user == "lin" else {}
        r = robot.put(f"/v1/users/{user}", json={**body, "learner": {"algorithm": "hri"}})
        assert r.status_code == 201, r.text
    for e in range(episodes + 10):
        for p, user in enumerate(PEOPLE):
            if e >= episodes and user != "lin":
                continue
            rng = random.Random(p * 100 + e)
            answer = people.person(need=NEEDS[p % 3], rng=rng, yes=0.8, asks=0.6, precise=0.5)
            play(robot, user, f"{user}-e{e}", answer)


class _Idle:
    """A worker's runner that runs nothing: the evaluations started stay queued."""

    def submit(self, evaluation_id: str) -> None:
        pass

    def stop(self, timeout: float = 5.0) -> bool:
        return True


def _console(
    app: FastAPI, make_key: MakeKey, episodes: int, *, runner: bool = True
) -> Iterator[Console]:
    robot = TestClient(app, headers={"Authorization": f"Bearer {make_key('robot', FLEET)}"})
    staff = make_key("staff", FLEET, "night-shift")
    api = TestClient(app, headers={"Authorization": f"Bearer {staff}"})
    client = TestClient(app, raise_server_exceptions=False, follow_redirects=False)
    client.cookies.set("attune_console", staff, path="/admin")
    with robot, api, client:
        _fill(robot, episodes)
        if not runner:
            app.state.evaluations = _Idle()
        yield Console(app, client, api, robot)


@pytest.fixture
def console(app: FastAPI, make_key: MakeKey) -> Iterator[Console]:
    """North with a little history: its evaluations are started here, not run (no runner)."""
    yield from _console(app, make_key, 2, runner=False)


@pytest.fixture
def evaluated(app: FastAPI, make_key: MakeKey) -> Iterator[Console]:
    """North with enough history for an evaluation to say something (twenty encounters of
    each person, thirty of Mrs. Lin's), run by the service's own runner."""
    yield from _console(app, make_key, 20)


def test_staff_start_an_evaluation_and_read_what_it_found(evaluated: Console) -> None:
    console = evaluated
    page = console.page().text
    assert 'id="nav-evaluations" aria-current="page">What if' in page
    assert "fleet north" in _words(page, "evaluations-fleet")
    assert _words(page, "no-evaluations") == "No evaluation of this fleet yet."
    # The plain-language choices, and the other learners' field, as attune evaluate reads them.
    for words in ("DTS", "HRI, explores less (τ = 0.005)", "HRI, explores more (τ = 0.1)"):
        assert f">{words}</label>" in page
    form = console.form(**{"pick-dts": "1", "pick-hri-less": "1", "other": "hri\n\n"})
    started = console.post(form)
    assert started.status_code == 303, started.text
    location = started.headers["location"]
    (job,) = console.evaluations()
    assert location == f"/admin/evaluations/{job['evaluation_id']}?fleet={FLEET}"
    assert [c["key"] for c in job["candidates"]] == ["dts", "hri:tau=0.005", "hri"]
    assert job["request_id"] == form["request_id"]
    assert job["requested_by"]["role"] == "staff"
    (entry,) = console.audit("evaluation.start")
    assert entry["target"] == job["evaluation_id"]
    assert entry["detail"]["candidates"] == ["dts", "hri:tau=0.005", "hri"]

    # The same form pressed again (a double click, a reload of the POST): the same evaluation.
    again = console.post(form)
    assert again.status_code == 303
    assert again.headers["location"] == location
    assert len(console.evaluations()) == 1
    assert len(console.audit("evaluation.start")) == 1

    # Its page follows it, then says what it found.
    assert console.looks() == []
    page = console.wait(location)
    found = console.api.get(
        f"/v1/admin/fleets/{FLEET}/evaluations/{job['evaluation_id']}", params={"persons": "false"}
    ).json()
    assert found["status"] == "done", found
    result = found["result"]
    assert _words(page, "evaluation-title") == "What if the robots used DTS, HRI τ=0.005 or HRI?"
    about = _words(page, "evaluation-about")
    assert about.startswith("Fleet north, all the history kept. Started ")
    assert " by night-shift." in about
    assert _words(page, "status-words").startswith("Done, ")
    assert 'data-active="false"' in page
    words = _text(page.split('id="verdicts"')[1].split("</ul>")[0])
    for c in result["candidates"]:
        if c["enough"]:
            assert c["verdict"][:1].upper() + c["verdict"][1:] + "." in words
        else:
            ess = f"{c['estimate']['ess']:.1f}"
            assert (
                f"{c['label']}: not enough evidence: {c['estimate']['n_episodes']} episodes, "
                f"effective size {ess}."
            ) in words
    # The robots' own learner, evaluated: about the same as what they do now, in words.
    assert re.search("HRI would earn about the same as what the robots do now: [+−]0.00 per", words)
    logged = result["logged"]
    assert _words(page, "logged-words") == (
        f"What the robots do now: they earn {logged['value']:.2f} per encounter (between "
        f"{logged['interval']['low']:.2f} and {logged['interval']['high']:.2f}), over 110 "
        "encounters with 5 people (the robots use HRI with 5 people)."
    )
    # The plot: drawn on the server, one row per learner beside what the robots do now.
    svg = page.split('<svg class="whatif-plot"')[1].split("</svg>")[0]
    assert svg.count('<g class="plot-row') == 1 + len(result["candidates"])
    assert '<g class="plot-row now">' in svg
    assert 'class="now-line"' in svg
    assert "<script" not in svg
    assert "style=" not in svg
    # The main view speaks staff words; the estimator's are folded under "how it was estimated".
    main = re.sub(r'<details class="card how".*?</details>', " ", page, flags=re.S)
    for jargon in ("wpdis", "importance", "bootstrap", "clip", "estimator", "ESS"):
        assert jargon not in _text(main), jargon
    how = _text(page.split('id="how"')[1].split("</details>")[0])
    assert "weighted per-decision importance sampling (wpdis)" in how
    assert "Effective sample size" in how
    assert f"attune evaluate --fleet {FLEET} --candidate dts" in how

    # Per person: each row links to the person's What if; each person named was looked at.
    table = page.split('id="persons"')[1].split("</table>")[0]
    assert sorted(re.findall(r'<tr data-user-id="([^"]+)"', table)) == sorted(PEOPLE)
    assert 'href="/admin/users/lin/whatif?fleet=north" class="person-link">lin</a>' in table
    lin = table.split('data-user-id="lin"')[1].split("</tr>")[0]
    assert re.search(r'<td class="num">30</td>', lin)
    assert "For lin, HRI would earn about the same as what the robots do now" in _text(lin)
    assert sorted(console.looks()) == [("evaluation", "console")] * len(PEOPLE)

    # The list: when, by whom, done, and a link to what it found; no look recorded there.
    listed = console.page().text
    row = listed.split(f'data-evaluation-id="{job["evaluation_id"]}"')[1].split("</tr>")[0]
    assert 'data-status="done"' in listed
    assert "night-shift" in row
    assert "DTS, HRI τ=0.005, HRI" in _text(row)
    assert ">Read what it found</a>" in row
    assert 'class="cancel"' not in row
    assert 'data-active="false"' in listed
    assert len(console.looks()) == len(PEOPLE)


def test_a_persons_what_if(evaluated: Console) -> None:
    console = evaluated
    # No evaluation yet: the tab says so, records no look, and leads to the fleet's page.
    page = console.page("/admin/users/lin/whatif").text
    assert 'id="tab-whatif" aria-current="page">What if' in page
    assert _words(page, "no-whatif") == (
        "No finished evaluation of fleet north counts Mrs. Lin's encounters yet. What if, for "
        "the fleet."
    )
    assert 'id="verdicts"' not in page
    assert console.looks() == []

    started = console.post(console.form(**{"pick-hri-less": "1", "other": "hri"}))
    location = started.headers["location"]
    console.wait(location)  # the fleet's page records its own looks
    before = len(console.looks())
    page = console.page("/admin/users/lin/whatif").text
    verdicts = page.split('id="person-verdicts"')[1].split("</ul>")[0]
    assert (
        "For Mrs. Lin, HRI would earn about the same as what the robots do now, as far as Mrs. "
        "Lin's encounters alone can tell: +0.00 per encounter (from 30 of Mrs. Lin's "
        "encounters)."
    ) in _text(verdicts)
    assert re.search(r'data-candidate="hri:tau=0.005" data-kind="(more|less|same|unknown)"', page)
    assert _words(page, "person-now").startswith("With Mrs. Lin, the robots earn ")
    assert _words(page, "person-now").endswith(" per encounter now (30 encounters counted).")
    evaluation_id = location.split("/evaluations/")[1].split("?")[0]
    assert f'href="/admin/evaluations/{evaluation_id}?fleet=north" id="fleet-evaluation"' in page
    # Reading it is a look at Mrs. Lin's data, said on her pages.
    assert console.looks()[before:] == [("evaluation", "console")]
    head = _words(console.page("/admin/users/lin/whatif").text, "looked")
    assert "(a what-if evaluation)" in head

    # A person whose encounters no evaluation counted: nothing to say.
    assert console.robot.put("/v1/users/newcomer", json={}).status_code == 201
    page = console.page("/admin/users/newcomer/whatif").text
    assert "No finished evaluation of fleet north counts newcomer's encounters yet." in _text(page)


def test_one_at_a_time_said_in_words_and_cancelled(console: Console) -> None:
    first = console.post(console.form(**{"pick-dts": "1"}))
    assert first.status_code == 303, first.text
    (job,) = console.evaluations()
    assert job["status"] == "queued"  # no runner here: it waits
    page = console.page(first.headers["location"]).text
    assert _words(page, "status-words") == (
        "Waiting to start: it starts once the evaluations before it are done"
    )
    assert 'data-active="true"' in page
    assert '<noscript><meta http-equiv="refresh" content="5"></noscript>' in page
    assert 'id="found"' not in page
    listed = console.page().text
    assert 'data-active="true"' in listed
    assert "Waiting to start" in _words(listed, "evaluations")

    # Another start, from a fresh form: refused in words, with what was chosen kept.
    busy = console.post(console.form(**{"pick-rmax": "1", "since": "2026-11-01"}))
    assert busy.status_code == 409, busy.text
    said = _words(busy.text, "form-errors")
    assert said.startswith(
        "Nothing was started. Another evaluation of this fleet is waiting to start (started "
    )
    assert "by night-shift): one evaluation of a fleet runs at a time." in said
    assert re.search(
        r'id="pick-rmax" name="pick-rmax" value="1" data-candidate="rmax" checked', busy.text
    )
    assert 'id="since" name="since" value="2026-11-01"' in busy.text
    assert len(console.evaluations()) == 1

    # Running, it says how far it is, and the 409 says so too.
    jobs_running = console.app.state.db
    with jobs_running.transaction() as session:  # as a runner takes it and says how far it is
        assert repo.claim(session, job["evaluation_id"], holder="test", now=utcnow())
        repo.progress(session, job["evaluation_id"], holder="test", done=2, total=5, now=utcnow())
    page = console.page(first.headers["location"]).text
    assert _words(page, "status-words") == "Running: 2 of 5 people"
    assert re.search(r'<progress id="progress" max="5" value="2"', page)
    listed = console.page().text
    assert re.search(r'<progress max="5" value="2" aria-label="People done"', listed)
    busy = console.post(console.form(**{"pick-rmax": "1"}))
    assert busy.status_code == 409
    assert "Another evaluation of this fleet is running (started " in _words(
        busy.text, "form-errors"
    )

    # Cancel, from the list: audited once, said in words.
    block = listed.split(f'data-evaluation-id="{job["evaluation_id"]}"')[1].split("</form>")[0]
    action = html.unescape(re.findall(r'<form method="post" action="([^"]+)"', block)[0])
    fields = dict(re.findall(r'<input type="hidden" name="(\w+)" value="([^"]*)"', block))
    cancelled = console.post(fields, path=action)
    assert cancelled.status_code == 303, cancelled.text
    assert cancelled.headers["location"] == f"/admin/evaluations?fleet={FLEET}&done=cancelled"
    page = console.page(cancelled.headers["location"]).text
    assert _words(page, "done-notice").startswith("Cancelled.")
    assert "Stopping: cancel was asked" in _words(page, "evaluations")
    assert 'class="cancel"' not in page  # asked once
    assert len(console.audit("evaluation.cancel")) == 1
    # The runner stops after the person in hand; then the fleet is free again.
    with jobs_running.transaction() as session:
        _, asked = repo.progress(
            session, job["evaluation_id"], holder="test", done=3, total=5, now=utcnow()
        )
        assert asked
        repo.finish(
            session,
            job["evaluation_id"],
            holder="test",
            status="cancelled",
            now=utcnow(),
            result=None,
            error=None,
        )
    assert _words(console.page().text, "evaluations").count("Cancelled") == 1
    again = console.post(console.form(**{"pick-rmax": "1"}))
    assert again.status_code == 303, again.text

    # A queued one is cancelled at once, from its own page.
    page = console.page(again.headers["location"]).text
    block = page.split('id="evaluation-status"')[1].split("</form>")[0]
    action = html.unescape(re.findall(r'<form method="post" action="([^"]+)"', block)[0])
    fields = dict(re.findall(r'<input type="hidden" name="(\w+)" value="([^"]*)"', block))
    done = console.post(fields, path=action)
    assert done.status_code == 303
    assert done.headers["location"] == again.headers["location"]
    page = console.page(done.headers["location"]).text
    assert _words(page, "status-words") == "Cancelled"
    assert 'data-active="false"' in page
    assert [e["status"] for e in console.evaluations()] == ["cancelled", "cancelled"]
    assert len(console.audit("evaluation.cancel")) == 2


@pytest.mark.parametrize(
    ("fields", "where", "says"),
    [
        ({}, "error-candidates", "Choose at least one learner to compare"),
        (
            {f"pick-{k}": "1" for k in ("dts", "hri-less", "hri-more", "qlearning", "rmax")}
            | {"other": "dts-adapt"},
            "error-candidates",
            "Choose at most 5 learners at a time (6 are chosen).",
        ),
        ({"pick-dts": "1", "other": "dts"}, "error-candidates", "DTS is chosen twice"),
        ({"other": "magic"}, "error-other", "Candidate 'magic': the algorithm must be one of"),
        ({"other": "hri:tau=-1"}, "error-other", "Candidate 'hri:tau=-1': "),
        ({"other": "hri:speed=3"}, "error-other", "speed"),
        (
            {"pick-dts": "1", "since": "yesterday"},
            "error-since",
            "Write the date as year-month-day",
        ),
        (
            {"pick-dts": "1", "since": "2026-11-10", "until": "2026-11-01"},
            "error-until",
            "The period ends before it starts",
        ),
        (
            {"pick-dts": "1", "estimator": "magic"},
            "error-estimator",
            "Choose the way of estimating",
        ),
    ],
)
def test_a_mistake_comes_back_in_words_and_starts_nothing(
    console: Console, fields: dict[str, str], where: str, says: str
) -> None:
    form = console.form(**fields)
    r = console.post(form)
    assert r.status_code == 422, r.text
    assert _words(r.text, "form-errors").startswith("Nothing was started.")
    assert says in _words(r.text, where)
    # What was typed is kept, under the same form number.
    if fields.get("other"):
        assert f">{html.escape(fields['other'])}</textarea>" in r.text
    assert f'name="request_id" value="{form["request_id"]}"' in r.text
    assert console.evaluations() == []
    assert console.audit("evaluation.start") == []


def test_one_day_periods_count_in_the_fleets_time_zone(console: Console) -> None:
    r = console.post(
        console.form(**{"pick-dts": "1", "since": "2026-11-01", "until": "2026-11-01"})
    )
    assert r.status_code == 303, r.text
    (job,) = console.evaluations()
    assert job["since"] == "2026-11-01T00:00:00+00:00"  # the fleet's time zone: UTC here
    assert job["until"] == "2026-11-02T00:00:00+00:00"  # the last day counts whole
    page = console.page(r.headers["location"]).text
    assert _words(page, "evaluation-about").startswith(
        "Fleet north, the episodes from 2026-11-01 00:00 until 2026-11-02 00:00."
    )


def test_a_form_from_elsewhere_is_refused(console: Console) -> None:
    form = console.form(**{"pick-dts": "1"})
    for bad in ({**form, "csrf": ""}, {**form, "csrf": "0" * 64}):
        r = console.post(bad)
        assert r.status_code == 403, r.text
        assert "Request refused" in r.text
    r = console.client.post(
        "/admin/evaluations", data=form, headers={"Origin": "https://evil.example"}
    )
    assert r.status_code == 403
    incomplete = console.post({**form, "request_id": ""})
    assert incomplete.status_code == 400
    assert "The form is incomplete" in _words(incomplete.text, "error-general")
    assert console.evaluations() == []
    assert console.audit("evaluation.start") == []


def test_another_fleets_staff_and_robots_see_none_of_it(
    app: FastAPI, console: Console, make_key: MakeKey
) -> None:
    started = console.post(console.form(**{"pick-dts": "1"}))
    location = started.headers["location"]
    evaluation_id = location.split("/evaluations/")[1].split("?")[0]
    # The job done, as the runner would leave it, so that its page would name people.
    jobs.run_job(app.state.db, app.state.ctx, evaluation_id)
    with TestClient(app, raise_server_exceptions=False, follow_redirects=False) as other:
        other.cookies.set(
            "attune_console", make_key("staff", "south", "south-staff"), path="/admin"
        )
        mine = other.get("/admin/evaluations")
        assert mine.status_code == 200  # their own fleet's: nothing
        assert 'id="no-evaluations"' in mine.text
        for path in (
            f"/admin/evaluations?fleet={FLEET}",
            location,
            f"/admin/evaluations/{evaluation_id}/progress?fleet={FLEET}",
            "/admin/users/lin/whatif?fleet=north",
        ):
            r = other.get(path)
            assert r.status_code in (403, 404), path
            assert "Mrs. Lin" not in r.text, path
            assert "lin" not in _text(r.text).split(), path
        # Without the fleet in the address, the id names no evaluation of their own fleet.
        r = other.get(f"/admin/evaluations/{evaluation_id}")
        assert r.status_code == 404
        token = re.search(r'name="csrf" value="([^"]+)"', mine.text)
        assert token is not None
        r = other.post(
            f"/admin/evaluations/{evaluation_id}/cancel?fleet={FLEET}",
            data={"csrf": token.group(1)},
        )
        assert r.status_code == 403
        r = other.post(
            f"/admin/evaluations?fleet={FLEET}",
            data={"csrf": token.group(1), "request_id": "x1", "pick-dts": "1"},
        )
        assert r.status_code == 403
    with TestClient(app, raise_server_exceptions=False, follow_redirects=False) as robot:
        key = make_key("robot", FLEET)
        signed = robot.post("/admin/login", data={"key": key, "next": "/admin/evaluations"})
        assert signed.status_code == 403
        assert "A staff or admin key is needed" in signed.text
        robot.cookies.set("attune_console", key, path="/admin")
        r = robot.get(location)
        assert r.status_code == 403
        assert 'id="verdicts"' not in r.text
    assert len(console.evaluations()) == 1
    assert console.looks() == []  # nobody's row was shown


def test_an_admin_chooses_the_fleet(app: FastAPI, console: Console, make_key: MakeKey) -> None:
    with TestClient(app, raise_server_exceptions=False, follow_redirects=False) as admin:
        admin.cookies.set("attune_console", make_key("admin", "default", "ops"), path="/admin")
        page = admin.get(f"/admin/evaluations?fleet={FLEET}")
        assert page.status_code == 200, page.text
        assert '<option value="north" selected>north</option>' in page.text
        assert f'action="/admin/evaluations?fleet={FLEET}" class="whatif-form"' in page.text
        block = page.text.split('id="evaluation-form"')[1].split("</form>")[0]
        hidden = dict(re.findall(r'<input type="hidden" name="(\w+)" value="([^"]*)"', block))
        r = admin.post(f"/admin/evaluations?fleet={FLEET}", data={**hidden, "pick-dts": "1"})
        assert r.status_code == 303, r.text
        assert r.headers["location"].endswith(f"?fleet={FLEET}")
        assert 'id="nav-evaluations"' in admin.get(r.headers["location"]).text
        # A fleet nobody is in yet: nothing to evaluate, said in words.
        empty = admin.get("/admin/evaluations?fleet=empty").text
        block = empty.split('id="evaluation-form"')[1].split("</form>")[0]
        hidden = dict(re.findall(r'<input type="hidden" name="(\w+)" value="([^"]*)"', block))
        r = admin.post("/admin/evaluations?fleet=empty", data={**hidden, "pick-dts": "1"})
        assert r.status_code == 404
        assert "Nobody in fleet empty yet" in _words(r.text, "error-general")
    (job,) = console.evaluations()
    assert job["requested_by"]["role"] == "admin"
    assert "ops" in _text(console.page().text)


def _candidate(label: str, value: float | None, low: float, high: float) -> dict[str, Any]:
    enough = value is not None
    return {
        "key": label.lower(),
        "label": label,
        "enough": enough,
        "reason": "" if enough else "not enough evidence: 30 episodes, effective size 4.2",
        "verdict": "",
        "estimate": {"value": value, "interval": None, "n_episodes": 30, "ess": 4.2},
        "difference": {"value": 0.0, "low": low, "high": high} if enough else None,
    }


def test_the_plot_reads_as_the_words() -> None:
    """A learner's bar is what the robots earn now plus the interval of the difference: it
    stays right of the line for "likely more", left for "likely less", across it for "about
    the same"; a learner without enough evidence has no dot."""
    result = {
        "logged": {"value": 2.0, "interval": {"low": 1.0, "high": 3.0}},
        "candidates": [
            _candidate("More", 2.4, 0.1, 0.7),
            _candidate("Less", 1.6, -0.7, -0.1),
            _candidate("Same", 2.1, -0.2, 0.3),
            _candidate("Unknown", None, 0.0, 0.0),
        ],
    }
    plot = views.evaluation_plot(result)
    now, more, less, same, unknown = plot.rows
    assert plot.now_x == now.x
    assert (now.kind, now.low, now.high) == ("now", None, None)
    assert plot.now_x is not None
    assert more.kind == "more"
    assert more.low is not None and more.low > plot.now_x  # noqa: PT018
    assert less.kind == "less"
    assert less.high is not None and less.high < plot.now_x  # noqa: PT018
    assert same.kind == "same"
    assert same.low is not None and same.high is not None  # noqa: PT018
    assert same.low < plot.now_x < same.high
    assert (unknown.kind, unknown.x) == ("unknown", None)
    assert plot.left <= min(r.low for r in (more, less, same) if r.low is not None)
    assert max(r.high for r in (more, less, same) if r.high is not None) <= plot.right
    assert [t.text for t in plot.ticks] == sorted((t.text for t in plot.ticks), key=float)
