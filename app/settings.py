"""Service settings: one ``Settings`` read from ``ATTUNE_*`` environment variables (or ``.env``)."""

from __future__ import annotations

import functools
import ipaddress
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    Field,
    PrivateAttr,
    SecretStr,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from app.daily import DailyTime

__all__ = ["Pooler", "Settings", "get_settings", "mask_url", "shown"]

Pooler = Literal["none", "transaction"]
"""What stands between the service and PostgreSQL (``ATTUNE_DATABASE_POOLER``)."""

SECRET_SETTINGS = frozenset({"metrics_token", "db_key"})
"""Settings whose values are never printed, whole or in part."""


def mask_url(url: str) -> str:
    """``url`` with its password (and a ``password=`` query parameter) replaced by ``***``,
    for every message that shows a database URL; also when the URL is malformed, so that a
    mistyped URL never prints its password either."""
    scheme, sep, rest = url.partition("://")
    if not sep:
        return url
    userinfo, at, after = rest.rpartition("@")  # a password may hold an unescaped "@"
    if at and ":" in userinfo:
        rest = f"{userinfo.split(':', 1)[0]}:***@{after}"
    path, q, query = rest.partition("?")
    if q:
        params = [
            f"{k}=***" if k.lower() == "password" else f"{k}{eq}{v}"
            for k, eq, v in (p.partition("=") for p in query.split("&"))
        ]
        rest = f"{path}?{'&'.join(params)}"
    return f"{scheme}://{rest}"


def shown(name: str, value: object) -> object:
    """A setting's value as a message may show it: a database URL without its password, a
    secret not at all."""
    if name in SECRET_SETTINGS:
        return "***"
    if name == "database_url" and isinstance(value, str):
        return mask_url(value)
    return value


def _ports_of(url: str) -> list[str]:
    """The texts after the hosts' colons in ``url``'s authority (``HOST:PORT,HOST:PORT``)."""
    rest = url.partition("://")[2]
    hosts = rest.rpartition("@")[2].split("/", 1)[0].split("?", 1)[0]
    ports = []
    for host in hosts.split(","):
        if host.startswith("["):  # [IPv6]:port
            host = host.partition("]")[2]
        if ":" in host:
            ports.append(host.rpartition(":")[2])
    return ports


def _read_key_file(path: Path) -> str:
    """The key in ``path``: its content without the surrounding whitespace (a final newline)."""
    try:
        return path.read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else "it is not UTF-8 text"
        raise ValueError(f"db_key_file cannot be read: {reason}.") from None


def _key_for_sqlite_only(info: ValidationInfo) -> None:
    """A database key is for SQLite: with a PostgreSQL URL it is a bad setting."""
    url = info.data.get("database_url")  # absent when the URL itself was wrong
    if isinstance(url, str) and not url.startswith("sqlite"):
        raise ValueError(
            "a database key is for an encrypted SQLite file; PostgreSQL is encrypted by its "
            "storage, and reached over TLS (docs/operations.md, Encryption at rest)."
        )


class Settings(BaseSettings):
    """Everything the service reads from its environment, with the defaults of a fresh machine."""

    # No value in the text of a validation error (a traceback shows that text): the commands
    # say what was wrong themselves, through ``shown``, which hides the secrets.
    model_config = SettingsConfigDict(
        env_prefix="ATTUNE_",
        env_file=".env",
        env_file_encoding="utf-8",
        extra="ignore",
        hide_input_in_errors=True,
    )

    database_url: str = Field(
        default="sqlite:///./attune.db",
        description="SQLAlchemy URL: sqlite:///PATH (embedded default) or "
        "postgresql+psycopg://USER@HOST:PORT/DB (production).",
    )
    db_key: SecretStr | None = Field(
        default=None,
        description="SQLite: the key the database file is encrypted with (SQLCipher, the "
        "encryption extra): a passphrase, or x'...' with 64 hex digits for a raw 256-bit key; "
        "surrounding whitespace is stripped. Never printed. Unset (and db_key_file unset): a "
        "plain SQLite file.",
    )
    db_key_file: Path | None = Field(
        default=None,
        description="SQLite: a file whose content, without surrounding whitespace, is the key "
        "(as db_key), read at start: for a key kept in a secrets mount. Set db_key or "
        "db_key_file, not both.",
    )
    database_pooler: Pooler = Field(
        default="none",
        description="PostgreSQL: what stands between the service and the database. transaction: "
        "a pooler in transaction pooling (PgBouncer's pool_mode=transaction), which may hand "
        "each transaction to another server connection, so the service prepares no statements "
        "on the server (psycopg's prepare_threshold=None) and keeps nothing on a connection "
        "between transactions. none: the service talks to PostgreSQL itself (or through a "
        "pooler in session pooling).",
    )
    seed: int = Field(
        default=0,
        ge=0,
        lt=2**63,
        description="Deployment seed: each user's decisions are drawn from a generator seeded "
        "by this seed, the user id and the decision's position in the user's history.",
    )
    mission_path: Path | None = Field(
        default=None, description="A mission JSON file; the built-in office mission if unset."
    )
    max_body_bytes: int = Field(
        default=64 * 1024, ge=1024, description="Largest request body accepted (413 above)."
    )
    sqlite_busy_timeout_s: float = Field(
        default=30.0, gt=0, description="How long a SQLite writer waits for the write lock."
    )
    sqlite_inline_writes: bool = Field(
        default=True,
        description="SQLite: run the robots' short writes on the worker's event "
        "loop when the database's write lock is free at once (else in the thread pool, as every "
        "other request).",
    )
    pg_inline_writes: Literal["auto", "true", "false"] = Field(
        default="auto",
        description="PostgreSQL: where the robots' short writes run. true: on the worker's "
        "event loop, on a connection of its own, when the user's lock is free at once (else in "
        "the thread pool, as every other request); false: always in the thread pool; auto: "
        "inline while the measured round trip to the database is below "
        "pg_inline_max_rtt_ms, else in the thread pool.",
    )
    pg_inline_max_rtt_ms: float = Field(
        default=0.3,
        gt=0,
        le=100,
        description="PostgreSQL, with pg_inline_writes=auto: the database round trip (measured "
        "at start and every few seconds) under which the robots' writes run on the event loop.",
    )
    loop_watch_ms: float = Field(
        default=10.0,
        ge=0,
        le=1000,
        description="How often each worker's watchdog wakes to measure how long its event loop "
        "was held up (attune_event_loop_stall_seconds); 0 turns it off.",
    )
    db_pool_size: int = Field(default=10, ge=1, description="Connections per worker process.")
    db_pre_ping: bool = Field(
        default=False,
        description="Test each pooled connection before use (one more round "
        "trip per transaction). Off: a connection broken by a database restart fails the one "
        "request that finds it (503, which clients retry) and the pool replaces them all.",
    )
    model_cache_size: int = Field(
        default=1024, ge=0, description="Decoded learners kept in memory per worker (0: none)."
    )
    key_cache_seconds: float = Field(
        default=5.0,
        ge=0,
        le=3600,
        description="How long a worker keeps an API key it authenticated before reading it "
        "from the database again: a key revoked by the command line or another worker keeps "
        "working for at most this long in each worker (0: read every request's key).",
    )
    snapshot_every: int = Field(
        default=16,
        ge=1,
        le=10_000,
        description="Store each user's learner state every this many model versions; between "
        "snapshots a write stores only the samples it taught, and a worker that does not have "
        "the learner in memory replays them onto the last snapshot (1: store it on every write).",
    )
    view_log_days: int = Field(
        default=365,
        ge=0,
        le=36_500,
        description="How long the record of who looked at a person's data keeps each entry, in "
        "days (older ones are removed as new ones are added; 0: kept until the person is "
        "erased).",
    )
    retention_batch: int = Field(
        default=500,
        ge=1,
        le=100_000,
        description="How many episodes (or journal entries) a retention run removes per "
        "transaction: smaller batches hold the database for less time at once.",
    )
    retention_at: Annotated[DailyTime | None, NoDecode] = Field(
        default=None,
        description="When set (HH:MM, in UTC, or HH:MM followed by an IANA time zone name: "
        "03:30 Europe/London), each running service starts the retention run of attune "
        "retention run once a day at that time, in the background; a lease in the database "
        "lets one process of the deployment run it at a time. Unset or empty: the service runs "
        "none (cron may run attune retention run).",
    )
    evaluation_max_minutes: float = Field(
        default=60.0,
        gt=0,
        le=24 * 60,
        description="An evaluation of candidate learners (POST /v1/admin/fleets/{fleet}/"
        "evaluations) that runs longer than this many minutes is stopped and marked failed; "
        "each worker runs one evaluation at a time, beside the robots' requests.",
    )
    rollout_guard_minutes: float = Field(
        default=60.0,
        ge=0,
        le=24 * 60,
        description="How often the service looks at every running rollout of a candidate "
        "learner and rolls back one whose candidate is worse with the comparison's confidence "
        "(one process of the deployment at a time); 0: never (staff roll back by hand).",
    )
    shadow_seconds: float = Field(
        default=30.0,
        ge=0,
        le=3600,
        description="How often the service lets each running shadow's candidate decide at the "
        "decisions of the episodes that ended since (one process of the deployment at a time); "
        "0: never.",
    )
    shadow_estimate_minutes: float = Field(
        default=60.0,
        gt=0,
        le=7 * 24 * 60,
        description="How often a running shadow's off-policy estimate (over the fleet's "
        "episodes since it started) is made again.",
    )
    prior_min_contributors: int = Field(
        default=5,
        ge=3,
        le=1000,
        description="A fleet's prior for newcomers is in force once at least this many of its "
        "people (with the newcomer's learner, enough episodes and the prior allowed) can "
        "contribute to it; fewer, and newcomers start from nothing.",
    )
    prior_min_episodes: int = Field(
        default=20,
        ge=1,
        le=1_000_000,
        description="The episodes a person needs before their model counts towards the fleet's "
        "prior.",
    )
    prior_max_contributors: int = Field(
        default=50,
        ge=3,
        le=10_000,
        description="The prior averages at most this many people: those whose models changed last.",
    )
    prior_strength: float = Field(
        default=4.0,
        gt=0,
        le=100,
        description="How many of a newcomer's own answers the fleet's prior weighs, per "
        "negotiation step it knows.",
    )
    log_level: str = Field(default="info", description="debug, info, warning or error.")
    log_format: str = Field(
        default="text",
        description="text (lines for people) or json (one JSON object per line for log "
        "shippers: time, level, logger, message, request_id, and the access line's method, "
        "route, status, latency_ms and key_id).",
    )
    rate_limit_per_s: float = Field(
        default=100.0,
        ge=0,
        description="Requests per second each API key may make, per worker process (a token "
        "bucket refilled at this rate; 0 turns the limit off). With --workers N a key may make "
        "up to N times this in all. Over it: 429 with Retry-After.",
    )
    rate_limit_burst: int = Field(
        default=2000,
        ge=1,
        description="Requests a key may make at once after being idle (the bucket's size): "
        "large enough for a robot that reconnects and replays what it buffered while offline.",
    )
    max_in_flight: int = Field(
        default=64,
        ge=1,
        description="Requests one worker process handles at once; more get 503 with "
        "Retry-After at once instead of waiting in an unbounded queue (/healthz, /readyz and "
        "/metrics are exempt).",
    )
    drain_timeout_s: float = Field(
        default=30.0,
        ge=0,
        le=3600,
        description="After SIGTERM or SIGINT, how long a worker goes on serving the requests in "
        "flight (and those that still reach it) before it stops; /readyz answers 503 from the "
        "signal on, and the worker stops as soon as no request is in flight.",
    )
    metrics_token: SecretStr | None = Field(
        default=None,
        description="When set, /metrics answers only requests with Authorization: Bearer "
        "<this token> (at least 16 characters); unset, it needs no key.",
    )
    metrics_port: int | None = Field(
        default=None,
        ge=1,
        le=65535,
        description="When set, attune serve serves /metrics on this port of --host, and not on "
        "the service's port; unset, on the service's port.",
    )

    root_path: str = Field(
        default="",
        description="The path prefix under which a reverse proxy serves the service (/attune): "
        "the proxy strips it before passing a request on, and the service puts it back in every "
        "link, redirect, cookie path and the documentation pages. Empty: served at /.",
    )
    forwarded_allow_ips: Annotated[list[str], NoDecode] = Field(
        default=["127.0.0.1", "::1"],
        description="The peers (IP addresses or CIDR networks, comma-separated; * for any) "
        "trusted as reverse proxies: their X-Forwarded-For, X-Forwarded-Proto and "
        "X-Forwarded-Host give the caller's address, scheme and host, and their X-Request-ID "
        "is kept. From any other peer these headers are dropped and the request gets an id of "
        "its own.",
    )

    _file_key: SecretStr | None = PrivateAttr(default=None)

    @field_validator("retention_at", mode="before")
    @classmethod
    def _daily_time(cls, value: object) -> object:
        return DailyTime.parse(value) if isinstance(value, str) else value

    @field_validator("root_path")
    @classmethod
    def _path_prefix(cls, value: str) -> str:
        value = value.strip().rstrip("/")
        if value and not (
            value.startswith("/")
            and "//" not in value
            and all((ch.isascii() and ch.isalnum()) or ch in "/-._~" for ch in value)
            and not {".", ".."} & set(value.split("/"))
        ):
            raise ValueError(
                "root_path must be empty or a path such as /attune (ASCII letters, digits and "
                "- . _ ~ between slashes; no . or .. segment)."
            )
        return value

    @field_validator("forwarded_allow_ips", mode="before")
    @classmethod
    def _proxies(cls, value: object) -> object:
        if isinstance(value, str):
            value = [part for part in (p.strip() for p in value.split(",")) if part]
        if not isinstance(value, list):
            return value
        for part in value:
            if part == "*":
                continue
            try:
                ipaddress.ip_network(str(part), strict=False)
            except ValueError:
                raise ValueError(
                    f"forwarded_allow_ips must list IP addresses or CIDR networks (or *), "
                    f"comma-separated; {part!r} is neither."
                ) from None
        return value

    @field_validator("database_url")
    @classmethod
    def _known_engine(cls, value: str) -> str:
        if value.startswith("postgresql://") or value.startswith("postgres://"):
            # psycopg 3 is the driver we ship; a bare postgresql:// URL would ask for psycopg2.
            value = "postgresql+psycopg://" + value.split("://", 1)[1]
        if not (value.startswith("sqlite") or value.startswith("postgresql+psycopg")):
            raise ValueError(
                "database_url must be sqlite:///PATH or postgresql+psycopg://USER@HOST/DB."
            )
        # Read it now, as the engine will: a malformed URL is a bad setting (one line, exit 2),
        # not a traceback from the first connection. Nothing of it but the port is quoted.
        if value.partition("://")[2].rpartition("@")[0].count("@"):
            raise ValueError("the user or password of database_url holds an '@': write it as %40.")
        for port in _ports_of(value):
            if not (port.isdigit() and 1 <= int(port) <= 65535):
                raise ValueError(
                    f"the port of database_url must be a number from 1 to 65535, not {port!r}."
                )
        from sqlalchemy.engine import make_url  # here: --help needs no SQLAlchemy

        try:
            make_url(value)
        except Exception:  # ArgumentError, or ValueError for a part it cannot read
            raise ValueError(
                "database_url is not a URL: write sqlite:///PATH or "
                "postgresql://USER:PASSWORD@HOST:PORT/DB."
            ) from None
        return value

    @field_validator("db_key")
    @classmethod
    def _key(cls, value: SecretStr | None, info: ValidationInfo) -> SecretStr | None:
        if value is None:
            return None
        _key_for_sqlite_only(info)
        key = value.get_secret_value().strip()
        if not key:
            raise ValueError("db_key is empty: set a key, or leave ATTUNE_DB_KEY unset.")
        return SecretStr(key)

    @field_validator("db_key_file")
    @classmethod
    def _key_file(cls, value: Path | None, info: ValidationInfo) -> Path | None:
        if value is None:
            return None
        if info.data.get("db_key") is not None:
            raise ValueError("set ATTUNE_DB_KEY or ATTUNE_DB_KEY_FILE, not both.")
        _key_for_sqlite_only(info)
        if not _read_key_file(value):
            raise ValueError("db_key_file is empty: it must hold the key.")
        return value

    @model_validator(mode="after")
    def _keep_file_key(self) -> Settings:
        if self.db_key_file is not None:
            self._file_key = SecretStr(_read_key_file(self.db_key_file))
        return self

    @field_validator("metrics_token")
    @classmethod
    def _long_token(cls, value: SecretStr | None) -> SecretStr | None:
        if value is not None and len(value.get_secret_value()) < 16:
            raise ValueError("metrics_token must be at least 16 characters long.")
        return value

    @field_validator("pg_inline_writes", mode="before")
    @classmethod
    def _inline_mode(cls, value: Any) -> str:
        """auto, or a boolean as pydantic reads one (true/false, 1/0, yes/no, on/off)."""
        text = str(value).strip().lower()
        if text in {"true", "1", "yes", "on"}:
            return "true"
        if text in {"false", "0", "no", "off"}:
            return "false"
        if text != "auto":
            raise ValueError("pg_inline_writes must be auto, true or false.")
        return text

    @field_validator("log_level")
    @classmethod
    def _known_level(cls, value: str) -> str:
        value = value.lower()
        if value not in {"debug", "info", "warning", "error"}:
            raise ValueError("log_level must be debug, info, warning or error.")
        return value

    @field_validator("log_format")
    @classmethod
    def _known_format(cls, value: str) -> str:
        value = value.lower()
        if value not in {"text", "json"}:
            raise ValueError("log_format must be text or json.")
        return value

    @property
    def is_sqlite(self) -> bool:
        return self.database_url.startswith("sqlite")

    @property
    def database_key(self) -> SecretStr | None:
        """The key of an encrypted SQLite database (``db_key``, or what ``db_key_file`` held at
        start), or None for a plain file."""
        return self.db_key if self.db_key is not None else self._file_key


@functools.lru_cache
def get_settings() -> Settings:
    """The process's settings, read once (tests pass their own ``Settings`` to ``create_app``)."""
    return Settings()
