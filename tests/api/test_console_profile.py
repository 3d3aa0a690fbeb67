"""A person's profile in the console, without a browser, on both engines: what the person wants
in words, the evidence of one box, corrections made and lifted through the page's forms (as the
staff key that is signed in), times in the person's local time, the header's episode count, and
no engineers' words on the pages staff use."""

from __future__ import annotations

import html
import re
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import update

from app.db.models import Episode
from app.db.session import Database
from tests.support import people
from tests.support.episodes import report, start
from tests.support.fixtures import MakeKey

FLEET = "north"
ZONE = "Asia/Shanghai"  # the fleet's time zone: UTC+8, as the robot's offsets
# Words of the engineers' views that must not reach the pages staff use (any case), and the
# learner's names of states and actions (as written).
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


class Console:
    """A browser signed in with a staff key of ``north`` (``api``: the same key on the v1 API);
    its robot made user ``lin`` with a few finished episodes (local time UTC+8) and one open."""

    def __init__(self, client: TestClient, api: TestClient, robot: TestClient) -> None:
        self.client, self.api, self.robot = client, api, robot

    def page(self, path: str) -> httpx.Response:
        r: httpx.Response = self.client.get(path)
        assert r.status_code == 200, r.text
        return r

    def form(self, path: str, form_id: str, **fields: str) -> dict[str, str]:
        """The hidden fields of form ``form_id`` on the page at ``path``, and ``fields``."""
        text = self.page(path).text
        block = text.split(f'id="{form_id}"')[1].split("</form>")[0]
        hidden = dict(re.findall(r'<input type="hidden" name="(\w+)" value="([^"]*)"', block))
        return {**{k: html.unescape(v) for k, v in hidden.items()}, **fields}

    def post(self, path: str, form: dict[str, str]) -> httpx.Response:
        r: httpx.Response = self.client.post(path, data=form)
        return r


def _play(robot: TestClient) -> None:
    """Three finished episodes in (afternoon, stretching), then one left open."""
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


@pytest.fixture
def console(app: FastAPI, make_key: MakeKey) -> Iterator[Console]:
    robot = TestClient(app, headers={"Authorization": f"Bearer {make_key('robot', FLEET)}"})
    staff = make_key("staff", FLEET)
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
        made = robot.put(
            "/v1/users/lin", json={"display_name": "Mrs. Lin", "learner": {"algorithm": "hri"}}
        )
        assert made.status_code == 201
        _play(robot)
        yield Console(client, api, robot)


def _text(page: str) -> str:
    """What a person reads on the page: the text and the attributes read aloud or shown
    (titles, labels), scripts and styles aside."""
    page = re.sub(r"<(script|style)\b.*?</\1>", " ", page, flags=re.S)
    attrs = " ".join(re.findall(r'(?:title|aria-label|placeholder)="([^"]*)"', page))
    return html.unescape(re.sub(r"<[^>]+>", " ", page) + " " + attrs)


def _cell(page: str, time_slot: str, situation: str) -> str:
    found = re.search(
        rf'<td class="pcell[^"]*" data-time-slot="{time_slot}" '
        rf'data-situation="{situation}".*?</td>',
        page,
        flags=re.S,
    )
    assert found, (time_slot, situation)
    return found.group(0)


def test_the_profile_speaks_in_words_and_counts_as_the_header(console: Console) -> None:
    profile: dict[str, Any] = console.api.get("/v1/users/lin/profile").json()
    page = console.page("/admin/users/lin").text
    assert 'id="tab-profile" aria-current="page"' in page
    cells = re.findall(r'<td class="pcell sure-(\w+)', page)
    assert len(cells) == len(profile["contexts"]) == 16
    for context in profile["contexts"]:
        cell = _cell(page, context["time_slot"], context["situation"])
        assert f'data-certainty="{context["certainty"]}"' in cell
        text = _text(cell)
        if context["wants"] is None and context["certainty"] == "unknown":
            assert "Not enough to say yet" in text
        assert any(
            w in text
            for w in (
                "Offers it without asking",
                "Offers help and asks",
                "Waits to be asked",
                "Stays away",
            )
        ), text
    # The header counts every episode, the open one said apart, as the grid does.
    assert profile["episodes"] == 4
    assert profile["open_episodes"] == 1
    assert sum(c["episodes"] for c in profile["contexts"]) == 4
    head = _text(page.split('id="episode-count"')[1].split("</span>")[0])
    assert re.sub(r"\s+", " ", head).strip().endswith("4 episodes (1 open)")
    assert 'data-episodes="4" data-open="1"' in page


def test_a_box_shows_its_evidence_in_local_time(console: Console) -> None:
    page = console.page("/admin/users/lin?time_slot=afternoon&situation=stretching").text
    evidence = page.split('id="evidence"')[1].split('id="corrections-card"')[0]
    profile = console.api.get("/v1/users/lin/profile").json()
    context = next(
        c
        for c in profile["contexts"]
        if (c["time_slot"], c["situation"]) == ("afternoon", "stretching")
    )
    facts = dict(re.findall(r'<dd data-fact="(\w+)">(.*?)</dd>', evidence, flags=re.S))
    assert facts["accepted"].startswith(f"{context['evidence']['accepted']} ")
    assert facts["refused"].startswith(f"{context['evidence']['refused']} ")
    assert re.sub(r"<[^>]+>", "", facts["last_seen"]) == (
        f"2026-11-22 15:10 (robot's time of the event, {ZONE})"
    )
    e = context["evidence"]
    assert facts["agree"] == (
        f"{e['support']} of the last {e['recent']} answer{'' if e['recent'] == 1 else 's'} agree"
    )
    assert html.escape(context["summary"], quote=False) in html.unescape(evidence) or context[
        "summary"
    ] in html.unescape(evidence)
    assert 'id="correction-form"' in evidence
    assert 'aria-current="true"' in _cell(page, "afternoon", "stretching")


def test_corrections_through_the_form(console: Console) -> None:
    where = "/admin/users/lin?time_slot=morning&situation=working"
    form = console.form(
        where,
        "correction-form",
        kind="prefers",
        service="ProvideDrink",
        detail="coffee",
        note="Her daughter says coffee first.",
    )
    assert len(form["correction_id"]) == 32
    assert (form["time_slot"], form["situation"]) == ("morning", "working")
    done = console.post("/admin/users/lin/corrections?fleet=north", form)
    assert done.status_code == 303, done.text
    assert done.headers["location"] == (
        "/admin/users/lin?fleet=north&time_slot=morning&situation=working&done=corrected#evidence"
    )
    again = console.post("/admin/users/lin/corrections?fleet=north", form)  # a double submit
    assert again.status_code == 303, again.text
    listed = console.api.get("/v1/users/lin/corrections")
    assert listed.status_code == 200, listed.text
    items = listed.json()["items"]
    assert [(c["kind"], c["service"], c["detail"]) for c in items] == [
        ("prefers", "ProvideDrink", "coffee")
    ]
    assert items[0]["note"] == "Her daughter says coffee first."
    assert items[0]["author"] in page_key_ids(console)
    page = console.page(done.headers["location"].split("#")[0]).text
    assert 'id="done-notice"' in page
    row = page.split('<tr data-correction-id="')[1].split("</tr>")[0]
    assert "Prefers Provide drink (coffee)" in row
    assert "Her daughter says coffee first." in row
    assert "In force" in row
    cell = _text(_cell(page, "morning", "working"))
    assert "Provide drink (coffee)" in cell
    assert "set by staff" in cell

    # Avoid and quiet, in other boxes; a mistake comes back in words with what was typed.
    where = "/admin/users/lin?time_slot=noon&situation=arriving"
    bad = console.post(
        "/admin/users/lin/corrections",
        console.form(where, "correction-form", kind="avoid", service="", note="typed"),
    )
    assert bad.status_code == 422
    assert "Choose what the robot should not offer." in html.unescape(bad.text)
    assert ">typed</textarea>" in bad.text
    for kind, service in (("avoid", "BriefInformation"), ("quiet", "")):
        r = console.post(
            "/admin/users/lin/corrections",
            console.form(where, "correction-form", kind=kind, service=service),
        )
        assert r.status_code == 303, r.text
    page = console.page("/admin/users/lin").text
    rows = re.findall(
        r'<tr data-correction-id="([^"]+)" data-status="(\w+)">(.*?)</tr>', page, flags=re.S
    )
    assert len(rows) == 3
    words = [
        re.search(r'<td class="what"><span class="words">(.*?)</span>', r[2]).group(1)  # type: ignore[union-attr]
        for r in rows
    ]
    assert sorted(words) == sorted(
        [
            "Prefers Provide drink (coffee)",
            "Do not offer Brief information",
            "Quiet: the robot does not offer help",
        ]
    )

    # Lifting one: its button's form posts the page's token.
    quiet = next(r[0] for r, w in zip(rows, words, strict=True) if w.startswith("Quiet"))
    token = re.search(r'name="csrf" value="([0-9a-f]{64})"', page)
    assert token
    lifted = console.post(
        f"/admin/users/lin/corrections/{quiet}/lift?fleet=north", {"csrf": token.group(1)}
    )
    assert lifted.status_code == 303, lifted.text
    assert "done=lifted" in lifted.headers["location"]
    page = console.page("/admin/users/lin").text
    assert "Quiet: the robot does not offer help" not in page
    assert len(re.findall(r"<tr data-correction-id=", page)) == 2
    # Without the page's token: refused, nothing changes.
    other = rows[0][0]
    refused = console.post(f"/admin/users/lin/corrections/{other}/lift", {"csrf": "0" * 64})
    assert refused.status_code == 403
    assert len(re.findall(r"<tr data-correction-id=", console.page("/admin/users/lin").text)) == 2


def page_key_ids(console: Console) -> list[str]:
    """The key id the console shows as signed in."""
    found = re.search(
        r'<span class="who"[^>]*>key ([^<]+)</span>', console.page("/admin/users").text
    )
    assert found
    return [found.group(1).strip()]


def test_episode_times_are_in_the_fleets_time_zone(console: Console, db: Database) -> None:
    with db.transaction() as session:  # an episode stored before offsets were kept
        session.execute(update(Episode).where(Episode.event_id == "e0").values(utc_offset=None))
    page = console.page("/admin/users/lin/episodes").text
    when = re.findall(r'<span class="when"><time datetime="[^"]+">(.*?)</time>', page)
    assert when == [  # the robot's time of each event, offset or not, in the fleet's zone
        "2026-11-23 09:30",
        "2026-11-22 15:10",
        "2026-11-21 15:10",
        "2026-11-20 15:10",
    ]
    assert f"Times are in the fleet&#39;s time zone, {ZONE}." in page
    assert "Robot's time of the event" in page
    contexts = re.findall(r'<span class="context">(.*?)</span>', page)
    assert contexts == ["morning, working"] + ["afternoon, stretching"] * 3
    assert "in progress" in page
    assert (
        re.sub(r"\s+", " ", _text(page.split('id="episode-count"')[1].split("</span>")[0]))
        .strip()
        .endswith("4 episodes (1 open)")
    )


def _staff_text(page: str) -> str:
    """What staff read on a page: everything but the engineers' parts, which stay folded
    under "Details for engineers"."""
    text = _text(re.sub(r'<details class="engineers".*?</details>', " ", page, flags=re.S))
    return re.sub(r"\s+", " ", text)


def _engineers_terms(text: str) -> list[str]:
    found = [w for w in ENGINEERS_WORDS if w.lower() in text.lower()]
    return found + [w for w in ENGINEERS_NAMES if re.search(rf"\b{w}\b", text)]


def test_staff_pages_hold_no_engineers_words(console: Console) -> None:
    form = console.form(
        "/admin/users/lin?time_slot=afternoon&situation=stretching",
        "correction-form",
        kind="prefers",
        service="ProvideDrink",
        detail="tea",
    )
    assert console.post("/admin/users/lin/corrections", form).status_code == 303
    episodes = console.page("/admin/users/lin/episodes").text
    traces = [html.unescape(u) for u in re.findall(r'data-trace-url="([^"]+)"', episodes)]
    assert len(traces) == 4  # every trace, the open one too
    where = "time_slot=afternoon&situation=stretching"
    pages = {
        "users": console.page("/admin/users").text,
        "mission": console.page("/admin/mission").text,
        "retention": console.page("/admin/retention").text,
        "profile": console.page("/admin/users/lin").text,
        "evidence": console.page(f"/admin/users/lin?{where}").text,
        "evidence, no episode": console.page(
            "/admin/users/lin?time_slot=night&situation=busy"
        ).text,
        "episodes": episodes,
        "why": console.page(f"/admin/users/lin/why?{where}").text,
        "why, no episode": console.page("/admin/users/lin/why?time_slot=noon&situation=busy").text,
        "reset": console.page("/admin/users/lin/reset").text,
        "delete": console.page("/admin/users/lin/delete").text,
        **{f"trace {i}": console.page(url).text for i, url in enumerate(traces)},
    }
    for name, page in pages.items():
        assert _engineers_terms(_staff_text(page)) == [], name
    # The why page says what drives the decision, in words: the correction first.
    why = _staff_text(pages["why"])
    assert "A staff correction decides first: Prefers Provide drink (tea)" in why
    assert "Mrs. Lin's own answers in 3 episodes here" in why
    assert "draws its choice from those estimates" not in why  # hri here, not DTS
    assert "sets aside old answers that contradict the latest one" in why
    # A trace, step by step, in words.
    trace = _staff_text(pages["trace 1"])
    assert "The robot " in trace
    assert "Mrs. Lin accepted" in trace or "Mrs. Lin answered" in trace
    # The engineers' terms are all still there: on the engineers' tab, and folded under
    # "Details for engineers" on the why page and in each trace.
    details = console.page("/admin/users/lin/details").text
    assert 'id="tab-details" aria-current="page"' in details
    assert 'id="heatmap"' in details
    assert 'id="model-version"' in details
    assert "hri τ=0.01" in details
    engineers = pages["why"].split('<details class="engineers"')[1]
    assert "n′" in engineers
    assert "ΔQ" in engineers
    assert "exp(Pref/τ)" in engineers
    assert "OBSERVE" in pages["trace 1"].split('<details class="engineers"')[1]


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"kind": "prefers", "service": ""}, "Choose what the person prefers."),
        (
            {"kind": "prefers", "service": "ProvideDrink", "detail": ""},
            "Choose the person's choice of Provide drink: tea, coffee or water.",
        ),
        (
            {"kind": "avoid", "service": "ProvideDrink", "detail": "news"},
            "“news” is not a choice of Provide drink: choose tea, coffee or water.",
        ),
        (
            {"kind": "avoid", "service": "Massage"},
            "The robots of fleet north do not offer “Massage” any more: choose another service.",
        ),
        (
            {"kind": "sing"},
            "Choose what to correct: what the person prefers, what the robot "
            "should not offer, or that the robot should stay quiet here.",
        ),
    ],
)
def test_mistakes_come_back_in_words(
    console: Console, fields: dict[str, str], message: str
) -> None:
    where = "/admin/users/lin?time_slot=evening&situation=working"
    r = console.post(
        "/admin/users/lin/corrections",
        console.form(where, "correction-form", note="as typed", **fields),
    )
    assert r.status_code == 422
    shown = re.search(
        r'<p class="field-error" id="correction-error" role="alert">(.*?)</p>', r.text
    )
    assert shown
    assert html.unescape(shown.group(1)) == message
    assert ">as typed</textarea>" in r.text
    assert console.api.get("/v1/users/lin/corrections").json()["items"] == []


def test_a_correction_the_persons_answers_overrode_says_so(console: Console) -> None:
    where = "/admin/users/lin?time_slot=afternoon&situation=stretching"
    form = console.form(
        where, "correction-form", kind="prefers", service="ProvideDrink", detail="coffee"
    )
    assert console.post("/admin/users/lin/corrections", form).status_code == 303
    for n in range(4):  # she keeps wanting tea: coffee is turned down
        episode = start(
            console.robot,
            "lin",
            f"tea-{n}",
            situation="stretching",
            occurred_at=f"2026-11-25T15:{10 + n:02d}:00+08:00",
        )
        decision = episode["decision"]
        while decision is not None:
            fields = people.answer(decision["action"], need=people.TEA)
            decision = report(
                console.robot, episode["episode_id"], decision["decision_id"], **fields
            )["decision"]
    (made,) = console.api.get("/v1/users/lin/corrections").json()["items"]
    assert made["status"] == "overridden", made
    page = console.page(where).text
    row = page.split('<tr data-correction-id="')[1].split("</tr>")[0]
    assert 'data-status="overridden"' in '<tr data-correction-id="' + row
    assert "Overridden by Mrs. Lin&#39;s own answers" in row
    assert 'id="changed"' in page


def test_a_new_person_and_an_unknown_box(console: Console) -> None:
    assert console.robot.put("/v1/users/new", json={}).status_code == 201
    page = console.page("/admin/users/new?time_slot=midnight&situation=flying").text
    assert page.count("Not enough to say yet") == 16 + 1  # the boxes, and the legend
    assert 'id="evidence-hint"' in page  # no such box: nothing opened
    assert 'id="no-corrections"' in page
    assert (
        re.sub(r"\s+", " ", _text(page.split('id="episode-count"')[1].split("</span>")[0]))
        .strip()
        .endswith("0 episodes")
    )
    page = console.page("/admin/users/new?time_slot=noon&situation=busy").text
    facts = dict(re.findall(r'<dd data-fact="(\w+)">(.*?)</dd>', page, flags=re.S))
    assert facts["last_seen"] == "never"
    assert facts["agree"] == "no answer yet"
    assert console.page("/admin/users/new/details").status_code == 200
    assert console.page("/admin/users/new/episodes").status_code == 200


def test_why_explains_the_learner_in_use(console: Console) -> None:
    made = console.robot.put("/v1/users/kim", json={"display_name": "Mr. Kim"})
    assert made.status_code == 201, made.text
    assert made.json()["learner"]["algorithm"] == "dts-routine"  # the service's default
    page = console.page("/admin/users/kim/why?time_slot=morning&situation=arriving").text
    words = _staff_text(page)
    assert "asks which service and which detail before guessing there again" in words
    assert "sets aside old answers" not in words  # that is HRI
    assert "has not met the robot here yet" in words
    legend = html.unescape(page.split('id="p-explained"')[1].split("</dd>")[0])
    assert "share of the drawn models in which this action is the best" in legend
    assert "Pref" not in legend
    assert "τ" not in legend
