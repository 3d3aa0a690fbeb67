"""What the robots' write path takes from libraries' undocumented internals, pinned: each test
fails with a sentence naming what changed when an upgrade of SQLAlchemy or FastAPI changes it.

- ``app.db.repositories._rows._Compiled`` (under ``Prepared``) reads a compiled statement's
  ``_bind_processors`` (each parameter's conversion for the dialect) and ``_result_columns``
  (its result columns' types). The result conversions come from the public
  ``TypeEngine.dialect_impl(dialect).result_processor(...)``.
- ``app.api.deps._lean_handler`` reads FastAPI's ``APIRoute.dependant`` (the parameters FastAPI
  worked out for the endpoint) and validates with its ``ModelField.validate``.
"""

from __future__ import annotations

import dataclasses
from datetime import UTC, datetime
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.routing import APIRoute
from sqlalchemy import Column, DateTime, Integer, MetaData, String, Table, bindparam, select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.engine import Dialect

from app.api.deps import CurrentPrincipal, TransactionalRoute, _lean_handler, inline
from app.db.repositories._rows import _Compiled

_t = Table(
    "pinned",
    MetaData(),
    Column("id", Integer, primary_key=True),
    Column("name", String(20)),
    Column("at", DateTime(timezone=True)),
)
DIALECTS = {"sqlite": sqlite.dialect(), "postgresql": postgresql.psycopg.dialect()}  # type: ignore[no-untyped-call]


@pytest.mark.parametrize("name", sorted(DIALECTS))
def test_a_compiled_statement_still_has_its_bind_processors_and_result_columns(
    name: str,
) -> None:
    dialect: Dialect = DIALECTS[name]
    stmt = select(_t.c.id, _t.c.name, _t.c.at).where(
        _t.c.at > bindparam("since", type_=_t.c.at.type), _t.c.name == bindparam("who")
    )
    compiled: Any = stmt.compile(dialect=dialect)
    assert hasattr(compiled, "_bind_processors"), (
        "SQLAlchemy's compiled statements no longer have _bind_processors: "
        "app/db/repositories/_rows.py (_Compiled) must get each parameter's conversion "
        "another way (bind_names and TypeEngine.bind_processor)"
    )
    procs = dict(compiled._bind_processors)
    public = {
        compiled.bind_names[bp]: bp.type.dialect_impl(dialect).bind_processor(dialect)
        for bp in compiled.bind_names
    }
    assert set(procs) <= set(public), (
        "SQLAlchemy's _bind_processors names parameters that the compiled statement's "
        f"bind_names do not ({sorted(set(procs) - set(public))}): its meaning changed"
    )
    for key, proc in procs.items():
        assert callable(proc), f"_bind_processors[{key!r}] is no longer a conversion"
        assert public[key] is not None, f"_bind_processors has {key!r}; the public API, none"
    assert hasattr(compiled, "_result_columns"), (
        "SQLAlchemy's compiled statements no longer have _result_columns: _Compiled must take "
        "the result columns' types another way (the statement's selected_columns)"
    )
    types = [entry.type for entry in compiled._result_columns]
    assert [type(t) for t in types] == [type(c.type) for c in stmt.selected_columns], (
        "SQLAlchemy's _result_columns no longer lists the result columns' types in order"
    )


@pytest.mark.parametrize("name", sorted(DIALECTS))
def test_the_statement_layer_converts_as_sqlalchemy_does(name: str) -> None:
    dialect = DIALECTS[name]
    stmt = select(_t.c.id, _t.c.at).where(_t.c.at > bindparam("since", type_=_t.c.at.type))
    compiled = _Compiled(stmt, dialect, None)
    when = datetime(2026, 11, 22, 7, 10, tzinfo=UTC)
    args = compiled.args({"since": when})
    expected = _t.c.at.type.dialect_impl(dialect).bind_processor(dialect)
    sent = args[0] if compiled.positional else args["since"]
    assert sent == (expected(when) if expected is not None else when)


def _robot_route() -> APIRoute:
    app = FastAPI()

    @inline
    async def write(user_id: str, body: dict[str, int], caller: CurrentPrincipal) -> Any:
        raise AssertionError("not called")

    app.router.route_class = TransactionalRoute
    app.router.add_api_route("/v1/things/{user_id}", write, methods=["POST"])
    route = app.router.routes[-1]
    assert isinstance(route, APIRoute)
    return route


def test_fastapi_still_describes_a_route_as_the_lean_handler_reads_it() -> None:
    route = _robot_route()
    assert hasattr(route, "dependant"), (
        "FastAPI's APIRoute has no dependant any more: app/api/deps.py (_lean_handler) must "
        "find the endpoint's parameters another way"
    )
    dependant = route.dependant
    read = {
        "dependencies",
        "path_params",
        "query_params",
        "header_params",
        "cookie_params",
        "call",
        "request_param_name",
        "response_param_name",
        "background_tasks_param_name",
        "http_connection_param_name",
        "websocket_param_name",
        "security_scopes_param_name",
    }
    have = {f.name for f in dataclasses.fields(dependant)}
    assert read <= have, (
        f"FastAPI's Dependant lost {sorted(read - have)}: app/api/deps.py (_lean_handler) "
        "reads them"
    )
    assert [p.alias for p in dependant.path_params] == ["user_id"]
    assert route.body_field is not None, "FastAPI's APIRoute.body_field is gone or empty"
    value, errors = route.body_field.validate({"a": 1}, {}, loc=("body",))
    assert (value, errors) == ({"a": 1}, []), (
        "FastAPI's ModelField.validate(value, values, loc=...) no longer answers "
        "(value, errors) as _lean_handler expects"
    )
    _, errors = route.body_field.validate({"a": "x"}, {}, loc=("body",))
    assert errors, "ModelField.validate no longer reports a refused body as errors"
    assert _lean_handler(route, route.get_route_handler()) is not None, (
        "the lean handler no longer recognises a robot write's route"
    )
