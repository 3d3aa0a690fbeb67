"""``/docs`` (Swagger UI) and ``/redoc`` (Redoc) render in a browser that can reach nothing but
the service on 127.0.0.1: their scripts and styles come from the service itself."""

from __future__ import annotations

from collections.abc import Iterator
from urllib.parse import urlsplit

import pytest
from playwright.sync_api import Browser, Route

from tests.support.live import LiveService, fresh_database

from .conftest import OUTPUT

pytestmark = [pytest.mark.browser, pytest.mark.xdist_group("browser")]


@pytest.fixture(scope="module")
def service() -> Iterator[LiveService]:
    with fresh_database("sqlite") as url, LiveService(url) as live:
        yield live


@pytest.mark.parametrize(
    ("path", "rendered", "asset"),
    [
        (
            "/docs",
            '.opblock-summary-path[data-path="/v1/users/{user_id}/episodes"]',
            "/static/docs/swagger-ui/swagger-ui-bundle.js",
        ),
        ("/redoc", "h2 >> text=Start Episode", "/static/docs/redoc/redoc.standalone.js"),
    ],
)
def test_docs_render_without_the_internet(
    browser: Browser, service: LiveService, path: str, rendered: str, asset: str
) -> None:
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    local: list[str] = []
    outside: list[str] = []

    def only_loopback(route: Route) -> None:
        url = route.request.url
        if urlsplit(url).hostname == "127.0.0.1":
            local.append(url)
            route.continue_()
        else:
            outside.append(url)
            route.abort()

    context.route("**/*", only_loopback)
    tab = context.new_page()
    errors: list[str] = []
    tab.on("pageerror", lambda exc: errors.append(str(exc)))
    # No error at all, not even the page's policy refusing a request to another host: the
    # pages ask for none (Redoc's sidebar logo from its maker's CDN is left out of the bundle).
    tab.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
    tab.on(
        "requestfailed",
        lambda request: (
            errors.append(f"failed: {request.url}")
            if urlsplit(request.url).hostname == "127.0.0.1"
            else None
        ),
    )
    try:
        tab.goto(service.url + path)
        tab.locator(rendered).first.wait_for(state="visible", timeout=30_000)
        tab.wait_for_load_state("networkidle")
        OUTPUT.mkdir(parents=True, exist_ok=True)
        tab.screenshot(path=str(OUTPUT / f"api{path.replace('/', '-')}.png"))
    finally:
        context.close()
    assert outside == [], outside
    assert errors == [], errors
    assert service.url + asset in local, local
    assert service.url + "/openapi.json" in local, local
