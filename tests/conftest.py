"""Fixtures shared by every test folder load here, as plugins (``tests/support``).

The kinds of test (pytest markers, registered in pyproject.toml; docs/development.md):
``live`` starts real ``attune serve`` processes, ``browser`` drives Chromium, ``stress`` runs the
lost-update and crash checkers, ``slow`` is a long seeded run. ``./scripts/test --fast`` leaves
those four out. ``one_engine`` runs a database test on SQLite only (``tests/support/fixtures``).
"""

pytest_plugins = ["tests.support.fixtures"]
