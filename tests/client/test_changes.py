"""The changes told to staff through the client: the requests ``list_changes`` and
``list_fleet_changes`` build are operations of the service's OpenAPI schema, the models read
every field the schema gives a change, and against the real application (in-process, on every
engine) they read what the service answers, page after page, with the errors it gives.

Lin wants tea in the afternoon while stretching, then coffee (as in ``tests/api/test_changes.py``):
her learner records the change, and staff read it through the client.
"""

from __future__ import annotations

import datetime as dt
import re
import typing
from collections.abc import Iterator
from typing import Any

import attune_client as a
import pytest
from attune_client._base import Api, Op
from fastapi import FastAPI
from fastapi.testclient import TestClient
from pydantic import BaseModel

from tests.support.episodes import play
from tests.support.fixtures import MakeKey
from tests.support.people import person

from .conftest import BASE_URL, PortalTransport, fast

TEA = ("ProvideDrink", "tea")
COFFEE = ("ProvideDrink", "coffee")

# Each client model and the schema component it reads.
MODELS: dict[type[BaseModel], str] = {
    a.ChangeList: "ChangeList",
    a.ChangeEvent: "ChangeEventOut",
    a.ChangeMoment: "Moment",
    a.ChangeEvidence: "EvidenceItem",
    a.Wanted: "Wanted",
}


def _operation(schema: dict[str, Any], op: Op[Any]) -> dict[str, Any]:
    """The schema's operation whose path template matches the request ``op`` builds."""
    for template, methods in schema["paths"].items():
        pattern = "^" + re.sub(r"\\{[^/]+\\}", "[^/]+", re.escape(template)) + "$"
        if re.match(pattern, op.path) and op.method.lower() in methods:
            found: dict[str, Any] = methods[op.method.lower()]
            return found
    raise AssertionError(f"no operation {op.method} {op.path} in the schema")


@pytest.mark.one_engine
def test_the_requests_are_the_schemas_operations(app: FastAPI) -> None:
    schema = app.openapi()
    since = dt.datetime(2026, 11, 27, tzinfo=dt.UTC)
    for op, path in (
        (Api.list_changes("lin", 50, "9"), "/v1/users/{user_id}/changes"),
        (Api.list_fleet_changes("care", since, 50, "9"), "/v1/admin/fleets/{fleet}/changes"),
    ):
        operation = _operation(schema, op)
        assert operation is schema["paths"][path]["get"]
        query = {p["name"]: p for p in operation["parameters"] if p["in"] == "query"}
        assert op.params is not None
        assert set(op.params) <= set(query), (path, set(op.params) - set(query))
        assert query["limit"]["schema"]["default"] == 50  # the client's default too
        answer = operation["responses"]["200"]["content"]["application/json"]["schema"]
        assert answer == {"$ref": "#/components/schemas/ChangeList"}
        assert "403" in operation["responses"]


@pytest.mark.one_engine
def test_the_models_read_every_field_of_the_schema(app: FastAPI) -> None:
    components = app.openapi()["components"]["schemas"]
    for model, name in MODELS.items():
        component = components[name]
        assert set(model.model_fields) == set(component["properties"]), name
        needed = {n for n, field in model.model_fields.items() if field.is_required()}
        assert needed <= set(component.get("required", [])), name  # nothing the service omits
    source = components["ChangeEventOut"]["properties"]["source"]
    assert set(typing.get_args(a.ChangeSource)) == set(source["enum"])


def _meet(robot: TestClient, first: int, last: int, need: tuple[str, str]) -> None:
    for i in range(first, last):
        when = dt.datetime(2026, 11, 20, 15, 10) + dt.timedelta(days=i)
        play(
            robot,
            "lin",
            f"lin-{i}",
            person(need=need, picky=True),
            situation="stretching",
            occurred_at=when.strftime("%Y-%m-%dT%H:%M:%S+08:00"),
        )


@pytest.fixture
def robot(app: FastAPI, make_key: MakeKey) -> Iterator[TestClient]:
    """A robot's ``TestClient``, to play Lin's episodes."""
    headers = {"Authorization": f"Bearer {make_key('robot')}"}
    with TestClient(app, headers=headers, client=("127.0.0.1", 50000)) as client:
        yield client


def test_staff_read_a_changed_wish_through_the_client(
    app: FastAPI, make_key: MakeKey, portal: PortalTransport, robot: TestClient
) -> None:
    staff_key = make_key("staff")
    with (
        fast(a.Client(BASE_URL, staff_key, transport=portal)) as staff,
        fast(a.Client(BASE_URL, make_key("robot"), transport=portal)) as robot_client,
        TestClient(app, headers={"Authorization": f"Bearer {staff_key}"}) as raw,
    ):
        staff.put_user("lin", learner={"algorithm": "dts-routine"})
        assert staff.list_changes("lin").items == []
        _meet(robot, 0, 12, TEA)
        _meet(robot, 12, 18, COFFEE)

        page = staff.list_changes("lin")
        (change,) = page.items
        assert page.next_cursor is None
        # Every field as the service sent it.
        answered = raw.get("/v1/users/lin/changes").json()["items"]
        assert [c.model_dump(mode="json") for c in page.items] == answered
        assert change.source == "routine"
        assert (change.time_slot, change.situation) == ("afternoon", "stretching")
        assert change.before == a.Wanted(service="ProvideDrink", detail="tea")
        assert change.since.episode == 13
        assert 13 <= change.decided.episode <= 18
        assert change.since.at.utcoffset() == dt.timedelta(hours=8)  # her local time
        assert [e.episode for e in change.evidence][0] == 13
        assert list(staff.iter_changes("lin", page_size=1)) == [change]

        # The fleet's page lists the same change; since a later time, none.
        assert staff.list_fleet_changes("default").items == [change]
        assert list(staff.iter_fleet_changes("default", page_size=1)) == [change]
        later = dt.datetime.now(dt.UTC) + dt.timedelta(minutes=5)
        assert staff.list_fleet_changes("default", since=later).items == []
        earlier = (dt.datetime.now(dt.UTC) - dt.timedelta(days=1)).isoformat()
        assert staff.list_fleet_changes("default", since=earlier).items == [change]

        # Robots read no changes; staff read no other fleet's; a naive time never leaves.
        with pytest.raises(a.PermissionDeniedError):
            robot_client.list_changes("lin")
        with pytest.raises(a.PermissionDeniedError):
            robot_client.list_fleet_changes("default")
        with pytest.raises(a.PermissionDeniedError):
            staff.list_fleet_changes("other")
        with pytest.raises(a.NotFoundError):
            staff.list_changes("nobody")
        with pytest.raises(a.UnprocessableEntityError):
            staff.list_fleet_changes("default", since="last week")
        with pytest.raises(ValueError, match="since needs a time zone"):
            staff.list_fleet_changes("default", since=dt.datetime(2026, 11, 27))
