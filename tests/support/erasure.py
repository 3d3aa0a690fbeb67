"""What is left of a person in a database: every table and column the database has, read from
the database itself (so a table added later is looked at without anyone listing it).

Two ways a row can still be the person's:

- **By reference**: a row whose foreign key points at the person's user row, or at a row that
  does, and so on (the foreign keys as the database declares them; a column named ``user_pk``
  without one counts as pointing at ``users.id``). The person's own number is the start even
  when their user row is gone, so orphans are found too.
- **By content**: a value of any column (JSON documents as their text) that contains one of the
  person's markers: texts only they have (their id, their display name, a staff note about
  them, their event ids). Their id may stay where the product keeps it on purpose: the audit
  log's ``target`` (:data:`ID_MAY_STAY`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from sqlalchemy import Engine, MetaData, inspect, select

__all__ = ["ID_MAY_STAY", "Subject", "remains"]

ID_MAY_STAY = {("audit_log", "target")}  # the pseudonymous id of an erased person's entries
_SKIP = {"alembic_version"}


@dataclass(frozen=True)
class Subject:
    pk: int  # users.id
    user_id: str
    markers: tuple[str, ...] = ()  # texts only this person has, besides their id
    id_is_marker: bool = True  # False: another fleet has a person of the same id


def _text(value: Any) -> str:
    if isinstance(value, dict | list):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, bytes | bytearray | memoryview):
        return bytes(value).decode("utf-8", "replace")
    return "" if value is None else str(value)


def remains(engine: Engine, subject: Subject) -> list[str]:
    """Each row of the database that is still ``subject``'s, as ``table: why``; empty when none
    is."""
    names = [t for t in inspect(engine).get_table_names() if t not in _SKIP]
    meta = MetaData()
    meta.reflect(engine, only=names)
    with engine.connect() as conn:
        rows = {t: [dict(r._mapping) for r in conn.execute(select(meta.tables[t]))] for t in names}
    found: list[str] = []

    # By reference: the rows reached from the person's number through foreign keys.
    links: list[tuple[str, tuple[str, ...], str, tuple[str, ...]]] = []
    for name in names:
        table = meta.tables[name]
        linked = False
        for fk in table.foreign_key_constraints:
            parent = fk.referred_table.name
            links.append(
                (name, tuple(fk.column_keys), parent, tuple(e.column.name for e in fk.elements))
            )
            linked = linked or parent == "users"
        if not linked and "user_pk" in table.c:
            links.append((name, ("user_pk",), "users", ("id",)))
    reached: dict[str, list[dict[str, Any]]] = {"users": [{"id": subject.pk}]}
    seen: set[tuple[str, int]] = set()
    grew = True
    while grew:
        grew = False
        for child, cols, parent, refcols in links:
            keys = {tuple(r.get(c) for c in refcols) for r in reached.get(parent, [])}
            for row in rows[child]:
                mark = (child, id(row))
                if mark not in seen and tuple(row[c] for c in cols) in keys:
                    seen.add(mark)
                    reached.setdefault(child, []).append(row)
                    found.append(f"{child}: a row that refers to the person ({row})")
                    grew = True
    found += [
        f"users: the person's row ({r})" for r in rows.get("users", []) if r["id"] == subject.pk
    ]

    # By content: the person's markers in any column.
    markers = [(m, False) for m in subject.markers]
    if subject.id_is_marker:
        markers.append((subject.user_id, True))
    for name in names:
        for row in rows[name]:
            for column, value in row.items():
                text = _text(value)
                for marker, is_id in markers:
                    if marker in text and not (is_id and (name, column) in ID_MAY_STAY):
                        found.append(f"{name}.{column}: holds {marker!r} ({text[:200]})")
    return found
