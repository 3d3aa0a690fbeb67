"""A person's model changes through one aggregate (``app.services.person_model``): no other
module of the service writes its head or its journal, nor reads the journal to rebuild it.

Read from the source (no database): the calls each module makes to the model head's writers
and to the journal's functions.
"""

from __future__ import annotations

import ast
from pathlib import Path

APP = Path(__file__).resolve().parents[2] / "app"
AGGREGATE = "app/services/person_model.py"
# The model head's writers (app.db.repositories.models) and the journal's functions
HEAD_WRITES = {"advance", "replace", "store_snapshot", "move_base", "snapshot", "base_state"}
# A retention run removes the folded journal a batch at a time, outside any one model's change
ALLOWED = {("app/services/retention.py", "journal", "delete_folded")}


def _calls(path: Path) -> set[tuple[str, str]]:
    """(module alias, function) of every ``alias.function(...)`` call whose alias names the
    models repository or the journal in this file's imports."""
    tree = ast.parse(path.read_text())
    aliases: dict[str, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module in (
            "app.db.repositories",
            "..db.repositories",
        ):
            for name in node.names:
                if name.name in ("models", "journal"):
                    aliases[name.asname or name.name] = name.name
    found = set()
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and isinstance(node.func.value, ast.Name)
            and node.func.value.id in aliases
        ):
            found.add((aliases[node.func.value.id], node.func.attr))
    return found


def test_only_the_aggregate_writes_a_model_or_its_journal() -> None:
    offenders = []
    for path in sorted(APP.rglob("*.py")):
        rel = path.relative_to(APP.parent).as_posix()
        if rel == AGGREGATE or rel.startswith("app/db/"):
            continue
        for module, function in _calls(path):
            if (rel, module, function) in ALLOWED:
                continue
            if module == "journal" or function in HEAD_WRITES:
                offenders.append(f"{rel}: {module}.{function}")
    assert offenders == [], offenders


def test_the_check_sees_a_write_outside_the_aggregate(tmp_path: Path) -> None:
    """The check is not blind: a module that advances a model itself is found."""
    bad = tmp_path / "bad.py"
    bad.write_text(
        "from app.db.repositories import models as models_repo\n"
        "from app.db.repositories import journal\n"
        "def f(s):\n"
        "    models_repo.advance(s, 1, version=2, updated_at=None)\n"
        "    journal.append(s, 1, [])\n"
    )
    assert _calls(bad) == {("models", "advance"), ("journal", "append")}
