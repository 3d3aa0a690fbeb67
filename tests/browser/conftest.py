"""The admin console in a real browser: headless Chromium (Debian's ``chromium``, which
``.ci/run`` installs) driven by Playwright, against a live ``attune serve`` on 127.0.0.1 whose
users and history were made through the v1 API.

Every test runs at a desktop (1280x800) and a tablet (800x1200) viewport, and saves a screenshot
of each page it visits under ``$ATTUNE_TEST_OUTPUT/browser/<viewport>/`` (default
``test-output/`` at the repository root). With ``ATTUNE_DOCS_SHOTS=1`` the screenshots that
docs/console.md shows are also written to ``docs/img/`` (``DOCS_SHOTS``).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.sync_api import Browser, Page, Response, ViewportSize, sync_playwright

from app.db.session import Database
from app.services.auth import create_key, revoke_key
from app.settings import Settings
from tests.support.live import LiveService, fresh_database

from .people import Person, meet

REPO = Path(__file__).resolve().parents[2]
OUTPUT = Path(os.environ.get("ATTUNE_TEST_OUTPUT") or REPO / "test-output") / "browser"
CHROMIUM = "/usr/bin/chromium"
# Without the background-networking switches Chromium's own connections (updates, sync, field
# trials) hang on a closed network and slow every launch.
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
VIEWPORTS: dict[str, ViewportSize] = {
    "desktop": {"width": 1280, "height": 800},
    "tablet": {"width": 800, "height": 1200},
}

# (viewport, screenshot) -> the docs/img file it becomes with ATTUNE_DOCS_SHOTS=1.
DOCS_SHOTS = {
    ("desktop", "login"): "console-login.png",
    ("desktop", "users"): "console-users.png",
    ("desktop", "profile"): "console-user.png",
    ("desktop", "profile-evidence"): "console-evidence.png",
    ("desktop", "profile-corrections"): "console-corrections.png",
    ("desktop", "details-lin"): "console-details.png",
    ("desktop", "why-words"): "console-why.png",
    ("desktop", "why"): "console-why-engineers.png",
    ("desktop", "episodes-words"): "console-episodes.png",
    ("tablet", "episodes-words"): "console-episodes-tablet.png",
    ("tablet", "why-words"): "console-why-tablet.png",
    ("tablet", "profile-corrections"): "console-corrections-tablet.png",
    ("desktop", "confirm-reset"): "console-confirm-reset.png",
    ("tablet", "profile"): "console-user-tablet.png",
    ("tablet", "profile-evidence"): "console-evidence-tablet.png",
    ("desktop", "retention"): "console-retention.png",
    ("desktop", "changes"): "console-changes.png",
    ("desktop", "profile-changes"): "console-profile-changes.png",
}
DOCS_IMG = REPO / "docs" / "img"

LIN_NEEDS = {
    ("afternoon", "stretching"): ("ProvideDrink", "tea"),
    ("morning", "arriving"): ("BriefInformation", "news"),
    ("morning", "working"): ("ArrangeSchedule", "today_agenda"),
}


@dataclass(frozen=True)
class Site:
    """The live service, its keys, and an admin API client for reading what the pages must show.

    Keys are made and revoked in this process, straight in the service's database with the
    services ``attune keys`` uses (a command-line round trip costs seconds on a busy machine).
    """

    url: str
    admin_key: str
    robot_key: str
    service: LiveService
    api: httpx.Client
    database: Database

    def get(self, path: str, **params: Any) -> Any:
        r = self.api.get(path, params=params)
        assert r.status_code == 200, r.text
        return r.json()

    def create_key(self, role: str, name: str) -> str:
        with self.database.transaction() as session:
            _, secret = create_key(session, role=role, name=name)
        return secret

    def revoke_key(self, key_id: str) -> None:
        with self.database.transaction() as session:
            revoke_key(session, key_id)


ZONE = "Asia/Shanghai"  # the fleet's time zone: UTC+8, as the offsets the robot sends


def _zone(api: httpx.Client) -> None:
    """The fleet's mission in force, with its time zone set (a display setting only)."""
    doc = api.get("/v1/mission").json()
    for name in ("fleet", "version", "fingerprint"):
        doc.pop(name)
    r = api.put(
        "/v1/admin/fleets/default/mission",
        json={"change_id": "zone", "mission": {**doc, "time_zone": ZONE}},
    )
    assert r.status_code == 200, r.text


def _seed(client: httpx.Client) -> None:
    def put(user_id: str, **body: Any) -> None:
        r = client.put(f"/v1/users/{user_id}", json=body)
        assert r.status_code in (200, 201), r.text

    put("lin", display_name="Mrs. Lin", learner={"algorithm": "hri"})  # the views of HRI
    meet(client, "lin", Person(LIN_NEEDS), 60, prefix="lin")
    put("chen", display_name="Mr. Chen", learner={"algorithm": "dts"})
    meet(
        client, "chen", Person({("noon", "working"): ("ProvideDrink", "coffee")}), 30, prefix="chen"
    )
    for viewport in VIEWPORTS:
        put(f"reset-{viewport}", display_name="Reset me")
        meet(client, f"reset-{viewport}", Person(LIN_NEEDS), 12, prefix="r")
        put(f"gone-{viewport}", display_name="Delete me")
        meet(client, f"gone-{viewport}", Person(LIN_NEEDS), 3, prefix="g")
    learners = ("hri", "rmax", "qlearning", "dts")
    for i in range(30):
        put(f"pager-{i:02d}", learner={"algorithm": learners[i % 4]})


@pytest.fixture(scope="package")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Site]:
    log = tmp_path_factory.mktemp("serve") / "attune-serve.log"
    with fresh_database("sqlite") as url, LiveService(url, log_path=log) as service:
        database = Database(Settings(database_url=url, _env_file=None))  # type: ignore[call-arg]
        with database.transaction() as session:
            _, admin_key = create_key(session, role="admin", name="console-tests")
            _, robot_key = create_key(session, role="robot", name="robot7")
        with httpx.Client(
            base_url=service.url, timeout=30, headers={"Authorization": f"Bearer {admin_key}"}
        ) as api:
            _zone(api)
        with httpx.Client(
            base_url=service.url, timeout=30, headers={"Authorization": f"Bearer {robot_key}"}
        ) as robot:
            _seed(robot)
        with httpx.Client(
            base_url=service.url, timeout=30, headers={"Authorization": f"Bearer {admin_key}"}
        ) as api:
            yield Site(service.url, admin_key, robot_key, service, api, database)
        database.dispose()


# Package scope: Playwright's event loop must be gone before the tests that come after this
# package (the async client's tests) start their own.
@pytest.fixture(scope="package")
def browser() -> Iterator[Browser]:
    if not Path(CHROMIUM).exists():
        pytest.fail(
            f"{CHROMIUM} is missing: install Debian's chromium package "
            "(apt-get install chromium; .ci/run does it).",
            pytrace=False,
        )
    with sync_playwright() as playwright:
        chromium = playwright.chromium.launch(
            executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS
        )
        yield chromium
        chromium.close()


@pytest.fixture(params=list(VIEWPORTS))
def viewport(request: pytest.FixtureRequest) -> str:
    name: str = request.param
    return name


@pytest.fixture
def page(browser: Browser, viewport: str) -> Iterator[Page]:
    """A fresh browser session (no cookie) at the viewport; fails the test on a script error or
    a console file that does not load."""
    context = browser.new_context(viewport=VIEWPORTS[viewport], accept_downloads=True)
    tab = context.new_page()
    tab.set_default_timeout(10_000)
    problems: list[str] = []
    tab.on("pageerror", lambda exc: problems.append(f"script error: {exc}"))

    def check(response: Response) -> None:
        if "/admin/static/" in response.url and response.status >= 400:
            problems.append(f"{response.url}: {response.status}")

    tab.on("response", check)
    yield tab
    context.close()
    assert not problems, problems


Shot = Callable[[Page, str], None]


@pytest.fixture
def shot(viewport: str) -> Shot:
    """``shot(page, name)``: check the page fits the viewport's width (tables scroll inside their
    own box), then save a full-page screenshot."""
    folder = OUTPUT / viewport
    folder.mkdir(parents=True, exist_ok=True)

    def take(tab: Page, name: str) -> None:
        tab.wait_for_load_state("load")
        overflow = tab.evaluate("document.documentElement.scrollWidth - window.innerWidth")
        assert overflow <= 0, f"{name} is {overflow} px wider than the {viewport} viewport"
        tab.screenshot(path=str(folder / f"{name}.png"), full_page=True)
        docs = DOCS_SHOTS.get((viewport, name))
        if docs and os.environ.get("ATTUNE_DOCS_SHOTS") == "1":
            tab.screenshot(path=str(DOCS_IMG / docs), full_page=True)

    return take


def sign_in(tab: Page, site: Site, key: str, path: str = "/admin/users") -> Response | None:
    """Open ``path`` (the console sends the browser to its login form) and submit ``key``."""
    tab.goto(site.url + path)
    assert "/admin/login" in tab.url
    tab.fill("#key", key)
    with tab.expect_response(
        lambda r: r.url.endswith("/admin/login") and r.request.method == "POST"
    ) as answer:
        tab.click("#login button[type=submit]")
    tab.wait_for_load_state("load")
    return answer.value


@pytest.fixture
def admin_page(page: Page, site: Site) -> Page:
    """A browser session signed in with the admin key."""
    sign_in(page, site, site.admin_key)
    assert page.url.endswith("/admin/users"), page.url
    return page
