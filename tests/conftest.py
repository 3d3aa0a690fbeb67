"""Fixtures shared by every test folder load here, as plugins (``tests/support``).

The kinds of test (pytest markers, registered in pyproject.toml; docs/development.md):
``live`` starts real ``attune serve`` processes, ``browser`` drives Chromium, ``stress`` runs the
lost-update and crash checkers, ``slow`` is a long seeded run. ``./scripts/test --fast`` leaves
those four out. ``one_engine`` runs a database test on SQLite only (``tests/support/fixtures``).
"""

from __future__ import annotations

import pytest

pytest_plugins = ["tests.support.fixtures"]


def pytest_runtest_setup(item: pytest.Item) -> None:
    """Under ``--dist loadgroup``, fail a test of an ``xdist_group`` that pytest-xdist did not
    keep with its group. xdist groups tests by appending ``@<group>`` to their ids; with a
    pytest whose ids it cannot change, the groups would silently fall apart."""
    if (getattr(item.config.option, "loadgroup", False)  # set on xdist's workers only
            and item.get_closest_marker("xdist_group") is not None and "@" not in item.nodeid):
        pytest.fail("pytest-xdist does not keep xdist_group tests together with this pytest: "
                    "pin pytest to a release it supports (pyproject.toml)", pytrace=False)
