"""ATTUNE_DATABASE_URL: what a message may show of it (never the password), and which URLs are
refused as a bad setting before anything connects."""

from __future__ import annotations

import pytest
from pydantic import SecretStr, ValidationError

from app.settings import Settings, mask_url, shown


@pytest.mark.parametrize(
    ("url", "masked"),
    [
        ("postgresql://attune:s3cret@db:5432/attune", "postgresql://attune:***@db:5432/attune"),
        (
            "postgresql+psycopg://attune:s3cret@db/attune",
            "postgresql+psycopg://attune:***@db/attune",
        ),
        # an unescaped "@" in the password: everything before the last one is hidden
        ("postgresql://attune:s3@cret@db/attune", "postgresql://attune:***@db/attune"),
        (
            "postgresql://attune:s3cret@db:notaport/attune",
            "postgresql://attune:***@db:notaport/attune",
        ),
        (
            "postgresql://db/attune?user=a&password=s3cret",
            "postgresql://db/attune?user=a&password=***",
        ),
        ("postgresql://attune@db/attune", "postgresql://attune@db/attune"),
        ("sqlite:///./attune.db", "sqlite:///./attune.db"),
        ("not a url", "not a url"),
    ],
)
def test_mask_url_hides_every_password(url: str, masked: str) -> None:
    assert mask_url(url) == masked
    assert "s3cret" not in mask_url(url)
    assert "cret" not in mask_url(url)


def test_shown_hides_secrets_and_passwords() -> None:
    assert shown("metrics_token", "a-long-metrics-token-value") == "***"
    assert shown("database_url", "postgresql://a:b@h/d") == "postgresql://a:***@h/d"
    assert shown("log_level", "loud") == "loud"


def _settings(url: str) -> Settings:
    return Settings(database_url=url, _env_file=None)  # type: ignore[call-arg]


@pytest.mark.parametrize(
    ("url", "says"),
    [
        ("postgresql://a:s3cret@db:notaport/x", "not 'notaport'"),
        ("postgresql://a:s3cret@db:0/x", "not '0'"),
        ("postgresql://a:s3cret@db:65536/x", "not '65536'"),
        ("postgresql://a:s3cret@db:5432,other:x/x", "not 'x'"),
        ("postgresql://a:s3@cret@db/x", "%40"),
        ("mysql://a:s3cret@db/x", "sqlite:///PATH"),
        ("postgresql+psycopg:/x", "not a URL"),
    ],
)
def test_a_malformed_url_is_a_bad_setting(url: str, says: str) -> None:
    with pytest.raises(ValidationError) as caught:
        _settings(url)
    (error,) = caught.value.errors()
    assert error["loc"] == ("database_url",)
    assert says in error["msg"]
    assert "s3cret" not in error["msg"]


@pytest.mark.parametrize(
    "url",
    [
        "sqlite:///./attune.db",
        "sqlite:////var/lib/attune/attune.db",
        "postgresql://attune:p%40ss@db.internal:5432/attune",
        "postgresql://attune@[::1]:5432/attune",
        "postgresql://attune@/attune?host=db1:5432&host=db2:5433",  # two hosts, as libpq
        "postgres://attune@db/attune",
    ],
)
def test_good_urls_pass(url: str) -> None:
    settings = _settings(url)
    assert settings.database_url.startswith(("sqlite", "postgresql+psycopg://"))


def test_a_short_metrics_token_is_refused_without_being_shown() -> None:
    with pytest.raises(ValidationError) as caught:
        Settings(metrics_token=SecretStr("short"), _env_file=None)  # type: ignore[call-arg]
    assert "16 characters" in str(caught.value.errors()[0]["msg"])
    token = Settings(metrics_token=SecretStr("x" * 16), _env_file=None)  # type: ignore[call-arg]
    assert "xxxxxxxxxxxxxxxx" not in repr(token)
