"""``attune serve``, ``attune db upgrade``, ``attune keys ...`` and ``attune models rebuild``."""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import socket
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn

import typer
from rich.console import Console

from app.errors import AppError, NotFound

from ._lazy import LazyModule, lazy_callable

if TYPE_CHECKING:
    from app.db import migrate
    from app.db.session import Database
    from app.settings import Settings
else:  # imported when a command runs: --help needs neither SQLAlchemy, Alembic nor pydantic
    migrate = LazyModule("app.db.migrate")
    Database = lazy_callable("app.db.session", "Database")
    Settings = lazy_callable("app.settings", "Settings")

__all__ = ["db", "keys", "models", "serve"]

err = Console(stderr=True)
log = logging.getLogger("attune")

db = typer.Typer(help="The database: ATTUNE_DATABASE_URL (default sqlite:///./attune.db).",
                 no_args_is_help=True)
keys = typer.Typer(help="API keys: made here, shown once, stored hashed.", no_args_is_help=True)
models = typer.Typer(help="Users' learned models.", no_args_is_help=True)


def _settings() -> Settings:
    try:
        return Settings()
    except Exception as exc:  # pydantic's ValidationError: say which variable is wrong
        typer.echo(_bad_settings(exc), err=True)
        raise typer.Exit(2) from None


def _bad_settings(exc: Exception) -> str:
    """One line per wrong ``ATTUNE_*`` variable: its name, what is wrong, what it was."""
    errors = getattr(exc, "errors", None)
    if not callable(errors):
        return f"Bad ATTUNE_* setting: {_one_line(exc)}."
    lines = []
    for e in errors():
        name = "ATTUNE_" + "_".join(str(part) for part in e.get("loc", ())).upper()
        message = str(e.get("msg", "invalid")).removeprefix("Value error, ").rstrip(".")
        lines.append(f"Bad setting {name}: {message} (got {e.get('input')!r}).")
    return "\n".join(lines) or f"Bad ATTUNE_* setting: {_one_line(exc)}."


class StartFailure(Exception):
    """Why the service (or a command) cannot start, as one sentence for the operator."""


def _fail(exc: StartFailure) -> NoReturn:
    typer.echo(str(exc), err=True)  # plain: rich would wrap the sentence at 80 columns
    raise typer.Exit(1)


def _one_line(exc: BaseException) -> str:
    """The first line of an error's message (a driver's hints follow on further lines)."""
    lines = str(getattr(exc, "orig", None) or exc).strip().splitlines()
    text = " ".join(lines[0].split()) if lines else ""
    return text.rstrip(".") or type(exc).__name__


def _sqlite_file(settings: Settings) -> Path | None:
    """The SQLite database's file, or None (PostgreSQL, or an in-memory database)."""
    if not settings.is_sqlite:
        return None
    from sqlalchemy.engine import make_url

    name = make_url(settings.database_url).database
    if not name or name == ":memory:" or name.startswith("file:"):
        return None
    return Path(name).absolute()


def _remove_sqlite(path: Path) -> None:
    for suffix in ("", "-wal", "-shm", "-journal"):
        Path(f"{path}{suffix}").unlink(missing_ok=True)


def _migrations_head() -> str | None:
    try:
        return migrate.head_revision()
    except Exception as exc:  # alembic's CommandError for a missing folder, or a broken script
        raise StartFailure("The database migrations that come with Attune cannot be read "
                           f"({_one_line(exc)}); reinstall Attune.") from exc


def _known_revision(url: str, revision: str) -> bool:
    from alembic.script import ScriptDirectory
    from alembic.util import CommandError

    try:
        ScriptDirectory.from_config(migrate.alembic_config(url)).get_revision(revision)
    except CommandError:
        return False
    return True


def _echo(line: str) -> None:
    typer.echo(line, err=True)  # plain: rich would wrap the line at 80 columns


def _upgrade(settings: Settings, *, report_current: bool = True,
             say: Callable[[str], None] = _echo) -> None:
    """Bring the database's schema up to date (telling ``say`` what was done), or raise
    :class:`StartFailure`.

    Nothing is touched before the migrations are found and the database's folder exists; a
    SQLite file made by a failed attempt is removed again.
    """
    head = _migrations_head()
    sqlite = _sqlite_file(settings)
    if sqlite is not None and not sqlite.parent.is_dir():
        raise StartFailure(f"The SQLite database {sqlite} cannot be made: the folder "
                           f"{sqlite.parent} does not exist.")
    made = sqlite is not None and not sqlite.exists()
    try:
        safe = Database(settings)
        url = safe.engine.url.render_as_string(hide_password=True)
        try:
            before = migrate.current_revision(safe.engine)
        except Exception as exc:  # the driver's error: refused, unknown host, bad password...
            raise StartFailure(f"Cannot reach the database {url}: {_one_line(exc)}.") from exc
        finally:
            safe.dispose()
        if before is not None and before != head and not _known_revision(settings.database_url,
                                                                           before):
            raise StartFailure(f"The database {url} has schema revision {before}, which this "
                               f"version of Attune (schema {head}) does not know: it was made "
                               "by a newer release; run that release, or restore a backup.")
        if before == head:
            if report_current:
                say(f"Database {url} is up to date (schema {head}).")
            return
        try:
            migrate.upgrade(settings.database_url)
        except Exception as exc:
            raise StartFailure(f"Upgrading the database {url} to schema {head} failed: "
                               f"{_one_line(exc)}.") from exc
        say(f"Database {url} upgraded: schema {before or 'empty'} -> {head}.")
    except BaseException:
        if made and sqlite is not None:
            _remove_sqlite(sqlite)
        raise


@contextmanager
def _database(settings: Settings) -> Iterator[Database]:
    """The database, its schema brought up to date first (a fresh machine has none yet)."""
    try:
        _upgrade(settings, report_current=False)
    except StartFailure as exc:
        _fail(exc)
    database = Database(settings)
    try:
        yield database
    finally:
        database.dispose()


def _listen(host: str, port: int) -> socket.socket:
    """The service's listening socket, bound before anything else is done (a port in use must
    not leave a database behind); uvicorn's workers share it."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise StartFailure(f"Port {port} on {host} is already in use: stop what uses it, or "
                               "pass another --port.") from None
        if exc.errno == errno.EACCES:
            raise StartFailure(f"Not allowed to listen on port {port} of {host}: pass a port "
                               "above 1023, or run with the rights to use it.") from None
        if exc.errno == errno.EADDRNOTAVAIL or isinstance(exc, socket.gaierror):
            raise StartFailure(f"Cannot listen on {host}: it is not an address of this "
                               "machine; pass another --host.") from None
        raise StartFailure(f"Cannot listen on {host}:{port}: "
                           f"{exc.strerror or _one_line(exc)}.") from None
    # uvicorn's own socket is made without IPPROTO_TCP, so asyncio does not turn Nagle's
    # algorithm off on the connections it accepts, and every response sent in two writes waits
    # for the client's delayed ACK (40 ms a request on Linux: 160 instead of 10,000 requests/s
    # for a bare app with 2 workers). Accepted connections inherit TCP_NODELAY from the
    # listener.
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.set_inheritable(True)
    return sock


def serve(
    host: Annotated[str, typer.Option(help="Interface to listen on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=1, max=65535, help="TCP port.")] = 8000,
    workers: Annotated[int, typer.Option(min=1, help="Worker processes (each with its own "
                                         "connection pool and learner cache).")] = 1,
) -> None:
    """Apply pending migrations, then serve the v1 API (docs at /docs).

    A start that cannot succeed (the port in use, the database unreachable, its schema from a
    newer release, the migrations missing) says why in one line and exits 1, leaving no new
    database file behind.
    """
    import logging.config

    import uvicorn

    from app import logs

    settings = _settings()
    log_config = logs.logging_config(settings.log_level, settings.log_format)
    logging.config.dictConfig(log_config)
    try:
        sock = _listen(host, port)
    except StartFailure as exc:
        _fail(exc)
    say = logging.getLogger("attune.serve").info  # a log line: JSON with ATTUNE_LOG_FORMAT=json
    try:
        try:
            _upgrade(settings, say=say)
        except StartFailure as exc:
            _fail(exc)
        if workers > 1 and not os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
            # Every worker writes its metrics here and /metrics adds them up.
            os.environ["PROMETHEUS_MULTIPROC_DIR"] = tempfile.mkdtemp(prefix="attune-metrics-")
        say(f"Attune on http://{host}:{port} (docs: http://{host}:{port}/docs), "
            f"{workers} worker(s).")
        # uvicorn's access log is off: the service writes one access line per request itself
        # (logger attune.access), with the route, the key id and the request id.
        config = uvicorn.Config("app.main:app", factory=True, host=host, port=port,
                                workers=workers, log_config=log_config,
                                log_level=settings.log_level, access_log=False,
                                proxy_headers=False)
        if workers == 1:
            with contextlib.suppress(KeyboardInterrupt):  # Ctrl+C: as uvicorn.run does
                uvicorn.Server(config).run(sockets=[sock])
            return
        from .supervisor import Supervisor

        Supervisor(config, sockets=[sock]).run()
    finally:
        sock.close()


@db.command("upgrade")
def db_upgrade() -> None:
    """Apply pending migrations to ATTUNE_DATABASE_URL and exit."""
    try:
        _upgrade(_settings())
    except StartFailure as exc:
        _fail(exc)


@db.command("current")
def db_current() -> None:
    """Print the schema revision of the database and of this code (nothing is changed: a
    SQLite file that does not exist is not made)."""
    settings = _settings()
    try:
        head = _migrations_head()
        sqlite = _sqlite_file(settings)
        if sqlite is not None and not sqlite.exists():
            current: str | None = None
            where = f" (no file at {sqlite})"
        else:
            database = Database(settings)
            url = database.engine.url.render_as_string(hide_password=True)
            try:
                current = migrate.current_revision(database.engine)
            except Exception as exc:  # the driver's error: refused, unknown host...
                raise StartFailure(f"Cannot reach the database {url}: {_one_line(exc)}.") \
                    from exc
            finally:
                database.dispose()
            where = ""
    except StartFailure as exc:
        _fail(exc)
    typer.echo(f"database: {current or 'empty'}{where}\ncode:     {head}")


@keys.command("create")
def keys_create(
    role: Annotated[str, typer.Option(help="robot or admin.")],
    fleet: Annotated[str, typer.Option(help="The fleet the key (and the users it creates) "
                                       "belongs to.")] = "default",
    name: Annotated[str | None, typer.Option(help="A label for people, e.g. 'robot7'.")] = None,
) -> None:
    """Make a key; the secret is printed once, alone on the last line."""
    from app.services.auth import create_key

    try:
        with _database(_settings()) as database, database.transaction() as session:
            key, secret = create_key(session, role=role, fleet=fleet, name=name)
    except AppError as exc:
        _say(exc.detail, "red")
        raise typer.Exit(2) from None
    _say(f"Created {key.role} key {key.id} for fleet {key.fleet!r}. Store the secret now: "
         "it cannot be shown again.")
    typer.echo(secret)


def _say(message: str, style: str = "") -> None:
    """One message on stderr, as it is (no markup), on one line however long."""
    from rich.text import Text

    err.print(Text(message, style=style), soft_wrap=True)


JsonOption = Annotated[bool, typer.Option("--json", help="Print JSON on stdout instead of a "
                                          "table.")]


@keys.command("list")
def keys_list(json_output: JsonOption = False) -> None:
    """List keys (ids, roles, fleets; never the secrets)."""
    from rich.table import Table

    from app.services.auth import list_keys

    from ._output import print_json, stdout_console

    with _database(_settings()) as database, database.transaction(write=False) as session:
        rows: list[dict[str, Any]] = [
            {"id": k.id, "role": k.role, "fleet": k.fleet, "name": k.name, "prefix": k.prefix,
             "created_at": k.created_at.isoformat(timespec="seconds"),
             "revoked_at": k.revoked_at.isoformat(timespec="seconds") if k.revoked_at else None}
            for k in list_keys(session)
        ]
    if json_output:
        print_json(rows)
        return
    table = Table("id", "role", "fleet", "name", "prefix", "created", "revoked")
    # The ids are what `keys revoke` takes: never cut, even on a narrow terminal.
    table.columns[0].no_wrap = True
    table.columns[0].min_width = max((len(r["id"]) for r in rows), default=2)
    for r in rows:
        table.add_row(r["id"], r["role"], r["fleet"], r["name"] or "", r["prefix"] + "…",
                      r["created_at"], r["revoked_at"] or "")
    stdout_console().print(table)


@keys.command("revoke")
def keys_revoke(key_id: Annotated[str, typer.Argument(help="The key's id (keys list).")]) -> None:
    """Revoke a key: its requests get 401 from now on. Revoking a revoked key changes nothing.
    Exit 2 if there is no such key."""
    from app.services.auth import revoke_key

    try:
        with _database(_settings()) as database, database.transaction() as session:
            key, changed = revoke_key(session, key_id)
    except AppError as exc:
        _say(exc.detail, "red")
        raise typer.Exit(2) from None
    if not changed:
        assert key.revoked_at is not None
        _say(f"Key {key_id} was already revoked at "
             f"{key.revoked_at.isoformat(timespec='seconds')}; nothing changed.")
        return
    _say(f"Revoked {key_id}: its requests get 401 from now on.")


@models.command("rebuild")
def models_rebuild(
    user_id: Annotated[str, typer.Argument(help="The user whose model to rebuild.")],
    save: Annotated[bool, typer.Option(help="Store the rebuilt model when it differs.")] = False,
) -> None:
    """Replay USER_ID's history into a fresh learner, redrawing every decision from the same seed
    stream, and compare with the stored model. Exit 0 when identical, 1 when not."""
    from app.services import audit
    from app.services.context import ServiceContext
    from app.services.models import rebuild_model

    settings = _settings()
    ctx = ServiceContext.from_settings(settings)
    try:
        with _database(settings) as database, database.transaction() as session:
            report = rebuild_model(session, ctx, audit.CLI, user_id, save=save)
    except NotFound:  # the command line sees every fleet: the user is not in the database
        _say(f"No user {user_id!r} in this database.", "red")
        raise typer.Exit(2) from None
    except AppError as exc:
        _say(exc.detail, "red")
        raise typer.Exit(2) from None
    summary = {
        "user_id": user_id, "version": report.version, "writes_replayed": report.writes,
        "samples_replayed": report.samples, "decisions_redrawn": report.decisions,
        "mismatched_decisions": report.mismatched_decisions, "identical": report.identical,
    }
    typer.echo(json.dumps(summary))
    if not report.identical:
        _say("The rebuilt model differs from the stored one."
             + (" Stored the rebuilt model." if save else ""), "red")
        raise typer.Exit(1)
    _say(f"Rebuilt {user_id}: identical to the stored model (version {report.version}).")
