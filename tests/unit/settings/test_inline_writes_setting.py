"""ATTUNE_PG_INLINE_WRITES: auto (the default), or a boolean in any of the ways pydantic reads
one; anything else is a bad setting with one sentence."""

from __future__ import annotations

from typing import Any

import pytest
from pydantic import ValidationError

from app.settings import Settings


def _settings(**kw: Any) -> Settings:
    return Settings(_env_file=None, **kw)  # type: ignore[call-arg]


def test_the_default_is_auto() -> None:
    assert _settings().pg_inline_writes == "auto"
    assert _settings().pg_inline_max_rtt_ms == 0.3


@pytest.mark.parametrize(
    ("given", "read"),
    [
        ("auto", "auto"),
        ("AUTO", "auto"),
        ("true", "true"),
        (True, "true"),
        ("1", "true"),
        ("on", "true"),
        ("false", "false"),
        (False, "false"),
        ("0", "false"),
        ("no", "false"),
    ],
)
def test_auto_or_a_boolean(given: object, read: str) -> None:
    assert _settings(pg_inline_writes=given).pg_inline_writes == read


def test_anything_else_is_refused_with_a_sentence() -> None:
    with pytest.raises(ValidationError, match="pg_inline_writes must be auto, true or false"):
        _settings(pg_inline_writes="sometimes")


@pytest.mark.parametrize("value", [0, -1, 101])
def test_the_round_trip_threshold_is_bounded(value: float) -> None:
    with pytest.raises(ValidationError):
        _settings(pg_inline_max_rtt_ms=value)
