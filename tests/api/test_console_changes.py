"""The console's pages of changes in what people want, without a browser, on both engines: the
fleet's "What changed this week" (``/admin/changes``), newest first, each change in words with
the person and the episodes that showed it; a person's profile page lists theirs; staff of
another fleet see neither."""

from __future__ import annotations

import html
import re
from collections.abc import Iterator

import httpx
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from tests.support.episodes import play
from tests.support.fixtures import MakeKey
from tests.support.people import person

FLEET = "north"


def _text(page: str) -> str:
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", " ", page)))


@pytest.fixture
def console(app: FastAPI, make_key: MakeKey) -> Iterator[tuple[TestClient, TestClient]]:
    """A browser signed in as north's staff, and north's robot; Lin took tea in the afternoon
    while stretching for eight episodes, then turned it down (she wants coffee)."""
    robot = TestClient(app, headers={"Authorization": f"Bearer {make_key('robot', FLEET)}"})
    staff = make_key("staff", FLEET, "day-shift")
    client = TestClient(app, raise_server_exceptions=False, follow_redirects=False)
    client.cookies.set("attune_console", staff, path="/admin")
    with robot, client:
        assert robot.put("/v1/users/lin", json={"display_name": "Mrs. Lin"}).status_code == 201
        for i in range(12):
            need = ("ProvideDrink", "tea") if i < 8 else ("ProvideDrink", "coffee")
            play(
                robot,
                "lin",
                f"lin-{i}",
                person(need=need),
                situation="stretching",
                occurred_at=f"2026-11-{10 + i}T15:10:00+08:00",
            )
        yield client, robot


def _get(client: TestClient, path: str) -> httpx.Response:
    r: httpx.Response = client.get(path)
    assert r.status_code == 200, r.text
    return r


def test_the_fleet_page_says_what_changed_in_words(
    console: tuple[TestClient, TestClient],
) -> None:
    client, _ = console
    page = _get(client, "/admin/changes").text
    assert 'id="nav-changes" aria-current="page">What changed' in page
    words = _text(page)
    assert "What changed this week" in words
    assert "Since 18 November, Mrs. Lin" in words
    assert 'class="who">lin</a>: Since 18 November' in page
    assert "tea" in words
    assert "in the afternoon, while stretching" in words
    # The person, at the context, and the episodes that showed it.
    assert (
        'href="/admin/users/lin?fleet=north&amp;time_slot=afternoon&amp;situation=stretching'
        in page
    )
    assert re.search(r'href="/admin/users/lin/episodes\?fleet=north&amp;at=9"', page)
    # A longer period lists it too; the person's page lists it.
    assert "Since 18 November" in _text(_get(client, "/admin/changes?days=30").text)
    profile = _text(_get(client, "/admin/users/lin").text)
    assert "What changed" in profile
    assert "Since 18 November, Mrs. Lin" in profile
    # and what the robot does there now
    assert "Now: In the afternoon, while stretching, Mrs. Lin" in profile


def test_staff_of_another_fleet_see_none_of_it(
    app: FastAPI, make_key: MakeKey, console: tuple[TestClient, TestClient]
) -> None:
    other = TestClient(app, raise_server_exceptions=False, follow_redirects=False)
    other.cookies.set("attune_console", make_key("staff", "south", "south-staff"), path="/admin")
    with other:
        r = other.get("/admin/changes?fleet=north")
        assert r.status_code == 403
        assert "Mrs. Lin" not in r.text
        mine = _text(_get(other, "/admin/changes").text)
        assert "Nothing changed this week" in mine
