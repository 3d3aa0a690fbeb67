"""docs/api.md documents exactly the operations of the service's OpenAPI schema.

An endpoint is documented by a level-3 heading that starts with its method and path in one code
span, as in /openapi.json (``### `GET /v1/users/{user_id}` ``). HEAD is documented once for every
GET, so a HEAD operation needs no heading of its own.
"""

from __future__ import annotations

import copy
from typing import Any

import pytest

from app.main import create_app
from app.settings import Settings

from .doccheck import ROOT, check_api_doc, documented_operations, schema_operations

API_DOC = ROOT / "docs" / "api.md"


@pytest.fixture(scope="module")
def schema(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    url = f"sqlite:///{tmp_path_factory.mktemp('api-doc') / 'attune.db'}"
    app = create_app(Settings(database_url=url, _env_file=None))  # type: ignore[call-arg]
    return app.openapi()


def test_every_operation_is_documented_and_nothing_else(schema: dict[str, Any]) -> None:
    report = check_api_doc(API_DOC.read_text(encoding="utf-8"), schema)
    assert report.ok, f"docs/api.md and /openapi.json differ:\n{report}"


def test_the_doc_lists_the_robots_loop(schema: dict[str, Any]) -> None:
    # A sanity check of the heading convention itself: the core endpoints are found.
    documented = set(documented_operations(API_DOC.read_text(encoding="utf-8")))
    assert ("POST", "/v1/users/{user_id}/episodes") in documented
    assert ("POST", "/v1/episodes/{episode_id}/outcomes") in documented
    assert len(documented) >= len({op for op in schema_operations(schema) if op[0] != "HEAD"})


def test_the_check_reports_a_removed_endpoint_and_an_extra_path(schema: dict[str, Any]) -> None:
    doc = API_DOC.read_text(encoding="utf-8")
    removed = "### `DELETE /v1/users/{user_id}`"
    assert removed in doc
    shortened = doc.replace(removed, "### Deleting a user")
    grown = copy.deepcopy(schema)
    grown["paths"]["/v1/robots/{robot_id}"] = {
        "get": {"responses": {"200": {}}},
        "head": {"responses": {"200": {}}},
    }
    grown["paths"]["/v1/users"]["post"] = {"responses": {"201": {}}}

    report = check_api_doc(shortened, grown)

    assert ("DELETE", "/v1/users/{user_id}") in report.missing
    assert ("GET", "/v1/robots/{robot_id}") in report.missing
    assert ("HEAD", "/v1/robots/{robot_id}") in report.missing  # its GET is not documented
    assert ("POST", "/v1/users") in report.missing
    assert not report.ok
    assert "undocumented in docs/api.md: DELETE /v1/users/{user_id}" in str(report)


def test_the_check_reports_a_documented_path_the_service_lacks(schema: dict[str, Any]) -> None:
    doc = API_DOC.read_text(encoding="utf-8") + "\n### `PATCH /v1/users/{user_id}`\n\nNo.\n"
    smaller = copy.deepcopy(schema)
    del smaller["paths"]["/v1/mission"]

    report = check_api_doc(doc, smaller)

    assert report.extra == [("GET", "/v1/mission"), ("PATCH", "/v1/users/{user_id}")]
    assert "documented but not served: PATCH /v1/users/{user_id}" in str(report)


def test_head_is_covered_by_its_get_and_headings_in_code_blocks_do_not_count() -> None:
    schema: dict[str, Any] = {"paths": {"/healthz": {"get": {}, "head": {}}, "/v1/x": {"post": {}}}}
    doc = "### `GET /healthz`\n\n```\n### `POST /v1/x`\n```\n"
    report = check_api_doc(doc, schema)
    assert report.missing == [("POST", "/v1/x")]
    assert report.extra == []


def test_a_heading_documented_twice_is_reported() -> None:
    schema: dict[str, Any] = {"paths": {"/healthz": {"get": {}}}}
    report = check_api_doc("### `GET /healthz`\n\n### `GET /healthz` again\n", schema)
    assert report.duplicated == [("GET", "/healthz")]


def _rights_table(doc: str) -> dict[str, tuple[set[str], set[str]]]:
    """The table under "Who may set what": field -> (roles on a new user, on one that exists)."""
    section = doc.split("#### Who may set what", 1)[1].split("\n#", 1)[0]
    rows: dict[str, tuple[set[str], set[str]]] = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0].startswith("`"):
            name = cells[0].split("`")[1]
            rows[name] = (set(cells[1].split(", ")), set(cells[2].split(", ")))
    return rows


def test_who_may_set_what_is_the_services_table() -> None:
    """api.md's table of field-level rights on PUT /v1/users/{user_id} is the service's."""
    from app.services.users import USER_FIELD_RIGHTS

    documented = _rights_table(API_DOC.read_text(encoding="utf-8"))
    assert documented == {
        name: (set(right.creates), set(right.changes)) for name, right in USER_FIELD_RIGHTS.items()
    }
