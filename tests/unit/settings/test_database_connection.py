"""What the service hands psycopg for a connection: TLS settings of the URL's query unchanged,
no server-side prepared statements behind a transaction pooler (ATTUNE_DATABASE_POOLER); and
which driver errors mean a lost connection (the pool drops it)."""

from __future__ import annotations

import sqlite3
from typing import Any

import psycopg
import pytest
from psycopg import errors
from pydantic import ValidationError
from sqlalchemy import event

from app.db.pool import is_lost_connection
from app.db.session import Database
from app.settings import Settings

TLS_URL = (
    "postgresql://attune@db.example.org:5432/attune"
    "?sslmode=verify-full&sslrootcert=/etc/attune/db-ca.pem"
)


class _Captured(Exception):
    """Raised instead of connecting: the connection's arguments were seen."""


def connect_params(settings: Settings) -> dict[str, Any]:
    """The keyword arguments the service's engine would pass to ``psycopg.connect``."""
    database = Database(settings)
    seen: dict[str, Any] = {}

    @event.listens_for(database.engine, "do_connect")
    def _capture(_dialect: Any, _record: Any, _args: Any, params: dict[str, Any]) -> None:
        seen.update(params)
        raise _Captured

    try:
        with pytest.raises(_Captured):
            database.engine.connect()
    finally:
        database.dispose()
    return seen


def _settings(**values: Any) -> Settings:
    return Settings(_env_file=None, **values)  # type: ignore[call-arg]


def test_tls_parameters_reach_psycopg_unchanged() -> None:
    settings = _settings(database_url=TLS_URL)
    assert settings.database_url == "postgresql+psycopg://" + TLS_URL.split("://", 1)[1]
    params = connect_params(settings)
    assert params["sslmode"] == "verify-full"
    assert params["sslrootcert"] == "/etc/attune/db-ca.pem"
    assert params["host"] == "db.example.org"


def test_a_transaction_pooler_gets_no_prepared_statements() -> None:
    pooled = connect_params(_settings(database_url=TLS_URL, database_pooler="transaction"))
    assert "prepare_threshold" in pooled
    assert pooled["prepare_threshold"] is None
    assert pooled["sslmode"] == "verify-full"  # the URL's own parameters stay
    assert "prepare_threshold" not in connect_params(_settings(database_url=TLS_URL))


def test_the_pooler_setting_is_read_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ATTUNE_DATABASE_POOLER", "transaction")
    assert _settings().database_pooler == "transaction"
    monkeypatch.setenv("ATTUNE_DATABASE_POOLER", "statement")
    with pytest.raises(ValidationError, match="database_pooler"):
        _settings()


@pytest.mark.parametrize(
    ("error", "lost"),
    [
        (psycopg.OperationalError("server closed the connection unexpectedly"), True),
        (psycopg.OperationalError("consuming input failed: EOF"), True),
        (psycopg.InterfaceError("the connection is closed"), True),
        (errors.AdminShutdown("terminating connection due to administrator command"), True),
        (errors.CrashShutdown("terminating connection because of crash"), True),
        (errors.CannotConnectNow("the database system is starting up"), True),
        (errors.ProtocolViolation("server conn crashed?"), True),  # PgBouncer's, 08P01
        (errors.LockNotAvailable("could not obtain lock"), False),
        (errors.QueryCanceled("canceling statement due to statement timeout"), False),
        (errors.UniqueViolation("duplicate key"), False),
        (errors.SerializationFailure("could not serialize access"), False),
        (sqlite3.OperationalError("database is locked"), False),
        (ValueError("not a driver error"), False),
    ],
)
def test_which_driver_errors_are_lost_connections(error: BaseException, lost: bool) -> None:
    assert is_lost_connection(error) is lost
