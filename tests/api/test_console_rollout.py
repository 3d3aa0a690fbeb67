"""The console's rollout page (``/admin/rollout``, its confirmations, and the line on a person's
profile), without a browser, on both engines: a shadow started from the form and stopped through
its confirmation, its sentence as the API's; a rollout started from the form through the same
service as ``PUT /v1/admin/fleets/{fleet}/rollout`` (audited there, the people moved), its groups
and sentence as the API's, its percentage changed (a lower one moves nobody, said so), promoted
and rolled back through confirmations (a reason kept); the guard's roll back said in words; the
person's line; mistakes and a rollout already running said on the form in words; and the
refusals (a form from elsewhere, another fleet's staff, a robot key)."""

from __future__ import annotations

import datetime as dt
import html
import re
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.console import views
from app.services import rollouts, shadows
from tests.support import people
from tests.support.arms import pin_even_salt
from tests.support.episodes import play
from tests.support.fixtures import MakeKey

FLEET = "north"
TEA = ("ProvideDrink", "tea")
HRI_LESS = "hri:tau=0.005"
LABEL = "HRI τ=0.005"
MAX_ROUNDS = 16  # a bound on the encounters of each person before the guard's test says worse


def _text(page: str) -> str:
    """What a reader sees: the tags gone, the spaces folded."""
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", " ", page))).strip()


def _words(page: str, where: str) -> str:
    """The text of the element with id ``where`` (to its first closing tag of that kind)."""
    found = re.search(rf'<(\w+)[^>]* id="{where}"[^>]*>(.*?)</\1>', page, flags=re.S)
    assert found, where
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", "", found.group(2)))).strip()


def _hidden(page: str, form_id: str) -> tuple[str, dict[str, str]]:
    """A form's action and hidden fields."""
    block = (
        page.split(f'id="{form_id}"')[0].rsplit("<form", 1)[1]
        + page.split(f'id="{form_id}"')[1].split("</form>")[0]
    )
    action = html.unescape(re.findall(r'action="([^"]+)"', block)[0])
    fields = dict(re.findall(r'<input type="hidden" name="(\w+)" value="([^"]*)"', block))
    return action, {k: html.unescape(v) for k, v in fields.items()}


class Console:
    """A browser signed in with a staff key of ``north`` named night-shift (``api``: the same
    key on the v1 API; ``robot``: north's robot)."""

    def __init__(
        self, app: FastAPI, client: TestClient, api: TestClient, robot: TestClient
    ) -> None:
        self.app, self.client, self.api, self.robot = app, client, api, robot

    def page(self, path: str = "/admin/rollout") -> str:
        r = self.client.get(path)
        assert r.status_code == 200, r.text
        return str(r.text)

    def submit(self, form_id: str, page: str | None = None, **fields: str) -> httpx.Response:
        """Fill the form ``form_id`` of ``page`` (a fresh rollout page) and post it."""
        action, hidden = _hidden(page or self.page(), form_id)
        r: httpx.Response = self.client.post(action, data={**hidden, **fields})
        return r

    def confirm(self, path: str, **fields: str) -> httpx.Response:
        """Open a confirmation page and press its button."""
        return self.submit("confirm-form", self.page(path), **fields)

    def rollout(self) -> dict[str, Any]:
        r = self.api.get(f"/v1/admin/fleets/{FLEET}/rollout")
        assert r.status_code == 200, r.text
        found: dict[str, Any] = r.json()
        return found

    def shadow(self) -> dict[str, Any]:
        r = self.api.get(f"/v1/admin/fleets/{FLEET}/shadow")
        assert r.status_code == 200, r.text
        found: dict[str, Any] = r.json()
        return found

    def audit(self, action: str) -> list[dict[str, Any]]:
        items = self.api.get("/v1/admin/audit", params={"limit": 200}).json()["items"]
        return [e for e in items if e["action"] == action]

    def learner(self, user: str) -> dict[str, Any]:
        learner: dict[str, Any] = self.api.get(f"/v1/users/{user}").json()["learner"]
        return learner

    def arms(self) -> dict[str, str]:
        """Each person's arm, as their profile says it."""
        out = {}
        for user in self.api.get("/v1/users", params={"limit": 100}).json()["items"]:
            arm = self.api.get(f"/v1/users/{user['user_id']}/profile").json()["rollout"]
            if arm is not None:
                out[user["user_id"]] = arm["arm"]
        return out


def _settle(app: FastAPI) -> None:
    """The moves a rollout owes, done (the worker's mover does them in the background, a person
    at a time, once the change is committed)."""
    if app.state.rollout_mover is not None:
        app.state.rollout_mover.join()
    rollouts.complete_moves(app.state.db, app.state.ctx)


def _people(robot: TestClient, n: int, episodes: int = 1) -> list[str]:
    users = [f"p{i:02d}" for i in range(n)]
    for user in users:
        r = robot.put(f"/v1/users/{user}", json={"learner": {"algorithm": "hri"}})
        assert r.status_code == 201, r.text
        for e in range(episodes):
            play(robot, user, f"{user}-e{e}", people.person(need=TEA))
    return users


@pytest.fixture(autouse=True)
def _even_arms(monkeypatch: pytest.MonkeyPatch) -> None:
    """Half of the people of each of these tests in each arm, give or take one: the tests
    compare the arms (a random salt leaves one nearly empty now and then)."""
    pin_even_salt(monkeypatch, [[f"p{i:02d}" for i in range(n)] for n in (4, 8, 12, 16)])


@pytest.fixture
def console(app: FastAPI, make_key: MakeKey) -> Iterator[Console]:
    robot = TestClient(app, headers={"Authorization": f"Bearer {make_key('robot', FLEET)}"})
    staff = make_key("staff", FLEET, "night-shift")
    api = TestClient(app, headers={"Authorization": f"Bearer {staff}"})
    client = TestClient(app, raise_server_exceptions=False, follow_redirects=False)
    client.cookies.set("attune_console", staff, path="/admin")
    with robot, api, client:
        yield Console(app, client, api, robot)


def _done(r: httpx.Response, done: str, **more: str) -> str:
    assert r.status_code == 303, r.text
    query = "".join(f"&{k}={v}" for k, v in more.items())
    assert r.headers["location"] == f"/admin/rollout?fleet={FLEET}&done={done}{query}"
    return r.headers["location"]


def test_a_shadow_started_read_in_words_and_stopped(app: FastAPI, console: Console) -> None:
    users = _people(console.robot, 6)
    page = console.page()
    assert 'id="nav-rollout" aria-current="page">Rollout' in page
    assert "fleet north" in _words(page, "rollout-fleet")
    assert 'id="shadow-now"' not in page
    assert 'id="rollout-now"' not in page
    # The What if form's learners, in its words, one to choose; all the people by default.
    for words in ("DTS", "HRI, explores less (τ = 0.005)", "R-MAX"):
        assert f">{words}</label>" in page
    assert 'id="shadow-percent" name="percent" value="100"' in page

    r = console.submit("shadow-form", learner="dts", percent="100")
    location = _done(r, "shadow-started")
    page = console.page(location)
    assert _words(page, "done-notice").startswith("It has started.")
    look = console.shadow()
    assert look["status"] == "running"
    assert look["share"] == 1.0
    assert look["candidate"]["key"] == "dts"
    assert _words(page, "shadow-summary") == look["summary"]
    assert look["summary"] == "DTS has not decided yet: it decides once an episode has ended."
    assert _words(page, "shadow-status").startswith("Running since ")
    assert "(started by night-shift), for 100% of the people." in _words(page, "shadow-status")
    assert 'id="shadow-form"' not in page  # one at a time: stop it first
    (entry,) = console.audit("shadow.start")
    assert entry["detail"]["candidate"] == "dts"

    # Once episodes ended, it says how often it would have done what the robots did, and what
    # it would likely earn.
    later = (dt.datetime.now(dt.UTC) + dt.timedelta(minutes=1)).isoformat()
    for e in range(3):
        for user in users:
            play(console.robot, user, f"{user}-s{e}", people.person(need=TEA), occurred_at=later)
    soon = dt.datetime.now(dt.UTC) + dt.timedelta(seconds=10)
    shadows.shadow_pass(app.state.db, app.state.ctx, now=soon)
    look = console.shadow()
    page = console.page()
    (candidate,) = look["estimate"]["candidates"]
    said = _words(page, "shadow-summary")
    assert said == look["agreement_summary"]
    assert look["summary"] == f"{said} {look['estimate_summary']}"
    assert candidate["verdict"] in look["estimate_summary"]
    assert re.fullmatch(
        r"DTS would have done what the robots did in [0-9]+% of [0-9,]+ decisions with 6 "
        r"people\.",
        said,
    ), said
    # What it would earn, as the What if page says it, without the estimator's terms.
    estimate = _words(page, "shadow-estimate")
    if candidate["enough"]:
        assert estimate.startswith(views.sentence(candidate["verdict"]))
    else:
        assert estimate.startswith("Not enough evidence yet to say what DTS would earn: ")
        assert "effective" not in estimate
    assert estimate.endswith(" (From the 18 encounters since it started.)")

    # Stopped through its confirmation.
    confirm = console.page(f"/admin/rollout/shadow/stop?fleet={FLEET}")
    assert "<h1>Stop trying DTS without acting?</h1>" in confirm
    assert "Nothing changes for anyone: it never acted." in _words(confirm, "confirm-text")
    assert 'id="nav-rollout" aria-current="page"' in confirm
    r = console.confirm(f"/admin/rollout/shadow/stop?fleet={FLEET}")
    page = console.page(_done(r, "shadow-stopped"))
    assert (
        _words(page, "done-notice")
        == "Stopped. What it decided so far stays below; it never acted."
    )
    assert console.shadow()["status"] == "stopped"
    assert len(console.audit("shadow.stop")) == 1
    assert "The last one: DTS" in _text(page)
    assert _words(page, "shadow-status").startswith("Stopped on ")
    assert " by night-shift; it ran from " in _words(page, "shadow-status")
    assert _words(page, "shadow-summary") == said  # what it decided stays
    assert 'id="shadow-form"' in page  # another may start
    assert 'id="stop-shadow"' not in page
    # Nothing runs any more: the confirmation says so.
    r = console.client.get(f"/admin/rollout/shadow/stop?fleet={FLEET}")
    assert r.status_code == 409
    assert "No shadow is running in fleet north: there is nothing to stop." in _text(r.text)
    assert 'data-status="409"' in r.text


def test_a_rollout_started_changed_promoted_then_another_rolled_back(
    app: FastAPI, console: Console
) -> None:
    users = _people(console.robot, 12)
    page = console.page()
    assert 'id="rollout-percent" name="percent" value="20"' in page
    r = console.submit("rollout-form", learner=HRI_LESS, percent="50")
    _settle(app)
    page = console.page(_done(r, "started"))
    assert _words(page, "done-notice").startswith("The rollout has started.")
    look = console.rollout()
    assert look["status"] == "running"
    assert look["share"] == 0.5
    assert look["candidate"]["key"] == HRI_LESS
    served = look["people"]["candidate"]
    assert 0 < served < len(users)
    assert served + look["people"]["control"] == len(users)
    (entry,) = console.audit("rollout.start")
    assert entry["detail"]["moved"] == served
    assert (entry["actor"]["role"], entry["actor"]["fleet"]) == ("staff", FLEET)
    arms = console.arms()
    for user, arm in arms.items():
        assert (console.learner(user)["params"]["tau"] == 0.005) == (arm == "candidate")

    # The groups, the sentence as the API's, where it stands.
    assert _words(page, "arm-candidate") == str(served)
    assert _words(page, "arm-control") == str(len(users) - served)
    assert _words(page, "rollout-summary") == look["summary"]
    assert look["summary"].startswith(f"Not enough evidence yet to compare {LABEL}")
    status = _words(page, "rollout-status")
    assert status.startswith("Running since ")
    assert status.endswith(" by night-shift, for 50% of the people.")
    assert f"Served by {LABEL}" in _words(page, "arms")
    assert 'id="rollout-plot"' not in page  # nothing to draw yet
    assert 'id="rollout-form"' not in page
    assert 'id="promote"' in page
    assert 'id="rollback"' in page

    # A person's profile says which group they are in.
    day = views.fmt_day(dt.datetime.now(dt.UTC), "UTC")
    mine = next(u for u, a in arms.items() if a == "candidate")
    theirs = next(u for u, a in arms.items() if a == "control")
    line = _words(console.page(f"/admin/users/{mine}"), "rollout-arm")
    assert (
        line == f"In the rollout of {LABEL}: served by the candidate since {day}. About the rollout"
    )
    line = _words(console.page(f"/admin/users/{theirs}"), "rollout-arm")
    assert line == f"In the rollout of {LABEL}: keeps the current learner. About the rollout"

    # A lower percentage moves nobody, and says so.
    assert "A lower one moves nobody" in _words(page, "share-hint-percent")
    r = console.submit("share-form", page, percent="25")
    page = console.page(_done(r, "share", moved="0"))
    assert "Nobody moved" in _words(page, "done-notice")
    assert console.arms() == arms
    assert console.rollout()["share"] == 0.25
    assert 'id="share-percent" name="percent" value="25"' in page
    # A higher one moves more people now.
    r = console.submit("share-form", page, percent="90")
    _settle(app)
    wider = console.rollout()["people"]["candidate"]
    assert wider > served
    page = console.page(_done(r, "share", moved=str(wider - served)))
    assert f"{wider - served} more " in _words(page, "done-notice")
    assert f"served by {LABEL} from now on" in _words(page, "done-notice")
    assert [e["detail"]["share"] for e in console.audit("rollout.share")] == [0.9, 0.25]

    # Promoted, through its confirmation.
    confirm = console.page(f"/admin/rollout/promote?fleet={FLEET}")
    assert f"<h1>Promote {LABEL}?</h1>" in confirm
    control = len(users) - wider
    people_words = "1 person" if control == 1 else f"{control} people"
    assert f"the {people_words} who keep the current learner move to {LABEL} now" in _words(
        confirm, "confirm-text"
    )
    assert f">Yes, promote {LABEL}</button>" in confirm
    r = console.confirm(f"/admin/rollout/promote?fleet={FLEET}")
    _settle(app)
    page = console.page(_done(r, "promoted"))
    assert console.rollout()["status"] == "promoted"
    (entry,) = console.audit("rollout.promote")
    assert entry["actor"]["key_id"] == console.rollout()["ended_by"]
    for user in users:
        assert console.learner(user)["params"]["tau"] == 0.005
    status = _words(page, "rollout-status")
    assert status.startswith("Promoted on ")
    assert f" by night-shift: {LABEL} serves everyone of the rollout" in status
    assert f"The last rollout: {LABEL}" in _text(page)
    assert 'id="promote"' not in page
    assert 'id="rollout-form"' in page  # another may start
    for user, arm in console.arms().items():  # the control people moved when it was promoted
        line = _words(console.page(f"/admin/users/{user}"), "rollout-arm")
        since = f" since {day}" if arm == "candidate" else ""
        assert line == f"Served by {LABEL}{since}: its rollout was promoted. About the rollout"

    # Another rollout, rolled back through its confirmation with a reason.
    r = console.submit("rollout-form", learner="dts", percent="50")
    _done(r, "started")
    _settle(app)
    second = console.rollout()
    assert second["candidate"]["key"] == "dts"
    confirm = console.page(f"/admin/rollout/rollback?fleet={FLEET}")
    assert "<h1>Roll back DTS?</h1>" in confirm
    assert 'id="reason"' in confirm
    # Too long a reason comes back in words, with what was written; nothing is rolled back.
    action, hidden = _hidden(confirm, "confirm-form")
    long = console.client.post(action, data={**hidden, "reason": "x" * 501})
    assert long.status_code == 422
    assert _words(long.text, "error-reason").startswith("Say why in at most 500 characters")
    assert 'data-status="422"' in long.text
    assert console.rollout()["status"] == "running"
    r = console.confirm(
        f"/admin/rollout/rollback?fleet={FLEET}", reason="the night staff saw more refusals"
    )
    _settle(app)
    page = console.page(_done(r, "rolled-back"))
    ended = console.rollout()
    assert ended["status"] == "rolled_back"
    assert ended["end_reason"] == "the night staff saw more refusals"
    (entry,) = console.audit("rollout.rollback")
    assert entry["detail"]["reason"] == "the night staff saw more refusals"
    assert _words(page, "done-notice").startswith("Rolled back.")
    status = _words(page, "rollout-status")
    assert status.startswith("Rolled back on ")
    assert status.endswith(" by night-shift, who said why: “the night staff saw more refusals”")
    for user in users:
        assert console.learner(user)["params"]["tau"] == 0.005  # what they had before DTS


def test_the_guards_roll_back_said_in_words(app: FastAPI, console: Console) -> None:
    users = _people(console.robot, 16)
    r = console.submit("rollout-form", learner=HRI_LESS, percent="50")
    _done(r, "started")
    _settle(app)
    arms = console.arms()
    assert sum(a == "candidate" for a in arms.values()) >= 5
    assert sum(a == "control" for a in arms.values()) >= 5
    # The candidate's people turn everything down; the others get their tea, until the
    # comparison says so (the interval narrows as the encounters add up; bounded).
    for round_ in range(MAX_ROUNDS):
        for user in users:
            who = people.person(need=None) if arms[user] == "candidate" else people.person(need=TEA)
            play(console.robot, user, f"{user}-g{round_}", who)
        look = console.rollout()
        if round_ >= 3 and look["comparison"]["verdict"] == "worse":
            break
    assert look["comparison"]["verdict"] == "worse", (look["comparison"], look["people"])
    page = console.page()
    assert _words(page, "rollout-summary") == look["summary"]
    assert f"{LABEL} earns less than the current learners: −" in look["summary"]
    assert 'class="verdict less" data-kind="less"' in page
    # The plot: the difference and its range, left of "no difference".
    svg = page.split('<svg class="whatif-plot rollout-plot"')[1].split("</svg>")[0]
    assert '<g class="plot-row less">' in svg
    assert "<script" not in svg
    assert "style=" not in svg
    zero = float(re.findall(r'<line class="now-line" x1="([0-9.]+)"', svg)[0])
    high = float(re.findall(r'<line class="interval" x1="[0-9.]+" x2="([0-9.]+)"', svg)[0])
    dot = float(re.findall(r'<circle class="dot" cx="([0-9.]+)"', svg)[0])
    assert dot <= high < zero
    # Per group: people, and encounters since they joined it.
    comparison = look["comparison"]
    table = page.split('id="arms"')[1].split("</table>")[0]
    row = table.split('data-arm="candidate"')[1].split("</tr>")[0]
    assert f'<td class="num">{comparison["candidate"]["n_episodes"]}</td>' in row

    assert rollouts.check_guard(app.state.db, app.state.ctx) == [FLEET]
    ended = console.rollout()
    assert ended["ended_by"] == "guard"
    page = console.page()
    status = _words(page, "rollout-status")
    assert status.startswith("Rolled back automatically by the guard on ")
    assert f", because {LABEL} earns less than the current learners: −" in status
    assert "the guard: " not in status
    assert f"The last rollout: {LABEL}" in _text(page)
    assert 'id="rollout-form"' in page
    mine = next(u for u, a in arms.items() if a == "candidate")
    line = _words(console.page(f"/admin/users/{mine}"), "rollout-arm")
    assert line.startswith(f"Was served by {LABEL} from ")
    assert "until its rollout was rolled back: back on the learner they had before." in line


def test_people_still_moving_are_said(
    app: FastAPI, console: Console, monkeypatch: pytest.MonkeyPatch
) -> None:
    """While the people a rollout moves are still being moved (this worker's mover stopped
    before it moved anyone), the page and their profile say so; once moved, they do not."""
    _people(console.robot, 8)
    monkeypatch.setattr(app.state, "rollout_mover", None)
    _done(console.submit("rollout-form", learner=HRI_LESS, percent="50"), "started")
    look = console.rollout()
    assert look["moving"] == look["people"]["candidate"] > 0
    n = look["moving"]
    who = "1 person is" if n == 1 else f"{n} people are"
    assert _words(console.page(), "rollout-moving") == (
        f"{who} still being moved to {LABEL}, one person at a time, keeping what the robots "
        "learned with them: it takes seconds (reload the page)."
    )
    mine = next(u for u, a in console.arms().items() if a == "candidate")
    line = _words(console.page(f"/admin/users/{mine}"), "rollout-arm")
    assert line == (
        f"In the rollout of {LABEL}: being moved to {LABEL}, keeping what was learned. About the "
        "rollout"
    )
    rollouts.complete_moves(app.state.db, app.state.ctx)
    assert 'id="rollout-moving"' not in console.page()
    line = _words(console.page(f"/admin/users/{mine}"), "rollout-arm")
    assert line.startswith(f"In the rollout of {LABEL}: served by the candidate since ")


@pytest.mark.parametrize("form", ["shadow-form", "rollout-form"])
@pytest.mark.parametrize(
    ("fields", "where", "says"),
    [
        ({"percent": "20"}, "learner", "Choose the learner to try."),
        ({"learner": "other", "percent": "20"}, "learner", "Write the other learner"),
        (
            {"learner": "other", "other": "magic", "percent": "20"},
            "learner",
            "Candidate 'magic': the algorithm must be one of",
        ),
        ({"learner": "other", "other": "hri:tau=-1", "percent": "20"}, "learner", "tau"),
        ({"learner": "dts", "percent": "0"}, "percent", "Write the percentage of people"),
        ({"learner": "dts", "percent": "150"}, "percent", "above 0 and at most 100"),
        ({"learner": "dts", "percent": "a fifth"}, "percent", "such as 20"),
        ({"learner": "dts", "percent": ""}, "percent", "such as 20"),
    ],
)
def test_a_mistake_comes_back_in_words_and_starts_nothing(
    console: Console, form: str, fields: dict[str, str], where: str, says: str
) -> None:
    _people(console.robot, 2)
    r = console.submit(form, **fields)
    assert r.status_code == 422, r.text
    name = form.removesuffix("-form")
    notice = f"{name}-errors"
    assert _words(r.text, notice) == "Nothing was started. See below."
    assert f'id="{notice}" data-status="422"' in r.text
    assert says in _words(r.text, f"{name}-error-{where}")
    # What was typed is kept.
    if fields.get("other"):
        assert f'id="{name}-other" name="other" value="{html.escape(fields["other"])}"' in r.text
    assert f'id="{name}-percent" name="percent" value="{fields["percent"]}"' in r.text
    assert console.audit("shadow.start") == []
    assert console.audit("rollout.start") == []


def test_one_at_a_time_said_in_words(console: Console) -> None:
    _people(console.robot, 4)
    page = console.page()
    _done(console.submit("rollout-form", page, learner=HRI_LESS, percent="50"), "started")
    _done(console.submit("shadow-form", page, learner="dts", percent="100"), "shadow-started")
    # Pressed again from the page as it was (another tab, the back button): said in words, what
    # was chosen kept, nothing changed.
    busy = console.submit("rollout-form", page, learner="rmax", percent="30")
    assert busy.status_code == 409, busy.text
    assert _words(busy.text, "rollout-errors") == (
        f"Nothing was started. A rollout of {LABEL} is already running in this fleet: promote "
        "it or roll it back before rolling out another learner."
    )
    assert 'id="rollout-errors" data-status="409"' in busy.text
    again = console.submit("rollout-form", page, learner=HRI_LESS, percent="30")
    assert again.status_code == 409  # the same learner: no share changed from the start form
    assert console.rollout()["share"] == 0.5
    busy = console.submit("shadow-form", page, learner="rmax", percent="100")
    assert busy.status_code == 409
    assert "A shadow of DTS is already running in this fleet: stop it" in _words(
        busy.text, "shadow-errors"
    )
    assert len(console.audit("rollout.start")) == 1
    assert len(console.audit("shadow.start")) == 1
    assert console.audit("rollout.share") == []

    # A mistake on the percentage of the running rollout: nothing changed.
    bad = console.submit("share-form", percent="0")
    assert bad.status_code == 422
    assert _words(bad.text, "share-errors") == "Nothing was changed. See below."
    assert "Write the percentage of people" in _words(bad.text, "share-error-percent")
    # A confirmation of a rollout that ended meanwhile (another one runs now) does nothing.
    stale = console.page(f"/admin/rollout/promote?fleet={FLEET}")
    _done(console.confirm(f"/admin/rollout/rollback?fleet={FLEET}"), "rolled-back")
    _done(console.submit("rollout-form", learner="dts", percent="50"), "started")
    r = console.submit("confirm-form", stale)
    assert r.status_code == 409
    assert "The rollout this form was about has ended meanwhile" in _text(r.text)
    assert console.rollout()["status"] == "running"
    assert console.audit("rollout.promote") == []
    # Nothing running: nothing to promote, roll back or change, said in words.
    _done(console.confirm(f"/admin/rollout/rollback?fleet={FLEET}"), "rolled-back")
    for path in ("/admin/rollout/promote", "/admin/rollout/rollback"):
        r = console.client.get(f"{path}?fleet={FLEET}")
        assert r.status_code == 409
        assert "No rollout is running in fleet north: there is nothing to " in _text(r.text)
    assert 'id="share-form"' not in console.page()


def test_a_form_from_elsewhere_is_refused(console: Console) -> None:
    _people(console.robot, 2)
    action, hidden = _hidden(console.page(), "rollout-form")
    form = {**hidden, "learner": "dts", "percent": "50"}
    for bad in ({**form, "csrf": ""}, {**form, "csrf": "0" * 64}):
        r = console.client.post(action, data=bad)
        assert r.status_code == 403, r.text
        assert "Request refused" in r.text
    r = console.client.post(action, data=form, headers={"Origin": "https://evil.example"})
    assert r.status_code == 403
    assert console.client.get(f"/v1/admin/fleets/{FLEET}/rollout").status_code == 401
    assert console.audit("rollout.start") == []


def test_another_fleets_staff_and_robots_are_refused(
    app: FastAPI, console: Console, make_key: MakeKey
) -> None:
    _people(console.robot, 4)
    _done(console.submit("rollout-form", learner=HRI_LESS, percent="50"), "started")
    _done(console.submit("shadow-form", learner="dts", percent="100"), "shadow-started")
    rollout_id = console.rollout()["rollout_id"]
    with TestClient(app, raise_server_exceptions=False, follow_redirects=False) as other:
        other.cookies.set(
            "attune_console", make_key("staff", "south", "south-staff"), path="/admin"
        )
        mine = other.get("/admin/rollout")
        assert mine.status_code == 200  # their own fleet's: nothing
        assert 'id="rollout-now"' not in mine.text
        assert LABEL not in mine.text
        for path in ("/admin/rollout", "/admin/rollout/promote", "/admin/rollout/rollback"):
            r = other.get(f"{path}?fleet={FLEET}")
            assert r.status_code == 403, path
            assert LABEL not in r.text
            assert 'data-status="403"' in r.text
        token = re.search(r'name="csrf" value="([^"]+)"', mine.text)
        assert token is not None
        for path, fields in (
            ("/admin/rollout", {"learner": "dts", "percent": "10"}),
            ("/admin/rollout/share", {"rollout_id": rollout_id, "percent": "10"}),
            ("/admin/rollout/promote", {"rollout_id": rollout_id}),
            ("/admin/rollout/rollback", {"rollout_id": rollout_id}),
            ("/admin/rollout/shadow", {"learner": "rmax", "percent": "10"}),
            ("/admin/rollout/shadow/stop", {}),
        ):
            r = other.post(f"{path}?fleet={FLEET}", data={"csrf": token.group(1), **fields})
            assert r.status_code == 403, path
    with TestClient(app, raise_server_exceptions=False, follow_redirects=False) as robot:
        key = make_key("robot", FLEET)
        signed = robot.post("/admin/login", data={"key": key, "next": "/admin/rollout"})
        assert signed.status_code == 403
        assert "A staff or admin key is needed" in signed.text
        robot.cookies.set("attune_console", key, path="/admin")
        r = robot.get("/admin/rollout")
        assert r.status_code == 403
        assert LABEL not in r.text
    look = console.rollout()
    assert (look["status"], look["share"]) == ("running", 0.5)
    assert console.shadow()["status"] == "running"
    assert len(console.audit("rollout.start")) == 1
    assert console.audit("rollout.share") == []


def test_an_admin_chooses_the_fleet(app: FastAPI, console: Console, make_key: MakeKey) -> None:
    _people(console.robot, 4)
    with TestClient(app, raise_server_exceptions=False, follow_redirects=False) as admin:
        admin.cookies.set("attune_console", make_key("admin", "default", "ops"), path="/admin")
        page = admin.get(f"/admin/rollout?fleet={FLEET}")
        assert page.status_code == 200, page.text
        assert '<option value="north" selected>north</option>' in page.text
        assert f'action="/admin/rollout?fleet={FLEET}" class="whatif-form rollout-form"' in (
            page.text
        )
        action, hidden = _hidden(page.text, "rollout-form")
        r = admin.post(action, data={**hidden, "learner": "other", "other": "hri:tau=0.02"})
        assert r.status_code == 422  # no percentage
        r = admin.post(
            action,
            data={**hidden, "learner": "other", "other": "hri:tau=0.02", "percent": "12.5"},
        )
        assert r.status_code == 303, r.text
        assert r.headers["location"] == f"/admin/rollout?fleet={FLEET}&done=started"
        status = _words(admin.get(r.headers["location"]).text, "rollout-status")
        assert status.endswith(" by ops, for 12.5% of the people.")
    look = console.rollout()
    assert (look["candidate"]["label"], look["share"]) == ("HRI τ=0.02", 0.125)
    assert " by ops, for 12.5% " in _words(console.page(), "rollout-status")


def _comparison(verdict: str, difference: float, low: float, high: float) -> dict[str, Any]:
    return {
        "enough": True,
        "verdict": verdict,
        "difference": difference,
        "low": low,
        "high": high,
    }


def test_the_plot_reads_as_the_words() -> None:
    """The bar is the difference's range: right of "no difference" for a learner that earns
    more, left for one that earns less, across it while no difference is shown; nothing is
    drawn without enough evidence."""
    more = views.rollout_plot(_comparison("better", 0.5, 0.2, 0.8))
    assert more is not None
    assert more.kind == "more"
    assert more.zero_x < more.low < more.x < more.high
    less = views.rollout_plot(_comparison("worse", -0.5, -0.9, -0.1))
    assert less is not None
    assert less.kind == "less"
    assert less.low < less.x < less.high < less.zero_x
    same = views.rollout_plot(_comparison("no difference yet", 0.1, -0.3, 0.5))
    assert same is not None
    assert same.kind == "same"
    assert same.low < same.zero_x < same.high
    for plot in (more, less, same):
        assert plot.left <= min(plot.low, plot.zero_x)
        assert max(plot.high, plot.zero_x) <= plot.right
        assert [t.text for t in plot.ticks] == sorted(
            (t.text for t in plot.ticks), key=lambda s: float(s.replace("−", "-"))
        )
    missing = {"enough": False, "verdict": "no difference yet", "difference": 0.1}
    assert views.rollout_plot({**missing, "low": None, "high": None}) is None
