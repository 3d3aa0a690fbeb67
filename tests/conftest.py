"""Fixtures shared by every test folder load here, as plugins (``tests/support``).

The kinds of test (pytest markers, registered in pyproject.toml; docs/development.md):
``live`` starts real ``attune serve`` processes, ``browser`` drives Chromium, ``stress`` runs the
lost-update and crash checkers, ``slow`` is a long seeded run. ``./scripts/test --fast`` leaves
those four out. ``one_engine`` runs a database test on SQLite only (``tests/support/fixtures``).
"""

from __future__ import annotations

from pathlib import Path

import pytest

pytest_plugins = ["tests.support.fixtures"]

TESTS = Path(__file__).parent
# Folders whose every test is of a kind ``--fast`` leaves out, so it does not even import them.
LEFT_OUT = {TESTS / "stress": "stress", TESTS / "fuzz": "live", TESTS / "topology": "live"}
SLOW_KINDS = ("live", "browser", "stress", "slow")


def pytest_runtest_setup(item: pytest.Item) -> None:
    """Fail a test of a folder that ``--fast`` skips whole (``LEFT_OUT``) that is not of a
    left-out kind: ``--fast`` would never run it. And, under ``--dist loadgroup``, fail a test
    of an ``xdist_group`` that pytest-xdist did not keep with its group. xdist groups tests by
    appending ``@<group>`` to their ids; with a pytest whose ids it cannot change, the groups
    would silently fall apart."""
    for folder, kind in LEFT_OUT.items():
        if item.path.is_relative_to(folder) and not any(
            item.get_closest_marker(k) for k in SLOW_KINDS
        ):
            pytest.fail(
                f"{item.nodeid}: every test of {folder.name}/ is of a kind that "
                f"./scripts/test --fast leaves out (it does not collect the folder): "
                f"mark it {kind}",
                pytrace=False,
            )
    if (
        getattr(item.config.option, "loadgroup", False)  # set on xdist's workers only
        and item.get_closest_marker("xdist_group") is not None
        and "@" not in item.nodeid
    ):
        pytest.fail(
            "pytest-xdist does not keep xdist_group tests together with this pytest: "
            "pin pytest to a release it supports (pyproject.toml)",
            pytrace=False,
        )
