"""``attune keys ...`` and ``attune models rebuild`` on SQLite and PostgreSQL: whole ids in the
table when the output is not a terminal, ``--json``, and what they say about keys and users
that are not there (or no longer usable)."""

from __future__ import annotations

import datetime as dt
import json
import re

from .conftest import Attune


def make_key(
    attune: Attune, role: str = "robot", fleet: str = "default", name: str | None = None
) -> str:
    """``attune keys create``: the new key's id (from its message)."""
    args = ["keys", "create", "--role", role, "--fleet", fleet]
    if name:
        args += ["--name", name]
    done = attune(*args)
    assert done.exit_code == 0, done.stderr
    assert done.stdout.startswith("att_")
    found = re.search(r"\b(key_[0-9a-f]{16})\b", done.stderr)
    assert found, done.stderr
    return found.group(1)


def test_keys_list_prints_whole_ids_when_not_a_terminal(attune: Attune) -> None:
    ids = [
        make_key(attune, name="a rather long label for the key of robot seven"),
        make_key(attune, "admin", fleet="warehouse-north-2"),
    ]
    done = attune("keys", "list")
    assert done.exit_code == 0, done.stderr
    rows = [line for line in done.stdout.splitlines() if "key_" in line]
    assert len(rows) == 2
    for key_id, row in zip(ids, rows, strict=True):
        assert key_id in row.split()  # one line per key, the id whole (no "key_fcaed5…")
    assert "warehouse-north-2" in done.stdout
    assert "a rather long label for the key of robot seven" in done.stdout
    header = next(line for line in done.stdout.splitlines() if " id " in line)
    assert [cell.strip() for cell in header.split("┃")[1:-1]] == [
        "id",
        "role",
        "fleet",
        "name",
        "prefix",
        "created",
        "revoked",
    ]  # no heading cut either


def test_keys_list_json(attune: Attune) -> None:
    assert json.loads(attune("keys", "list", "--json").stdout) == []
    robot = make_key(attune, name="robot7")
    admin = make_key(attune, "admin", fleet="north")
    assert attune("keys", "revoke", robot).exit_code == 0
    done = attune("keys", "list", "--json")
    assert done.exit_code == 0, done.stderr
    keys = {k["id"]: k for k in json.loads(done.stdout)}  # stdout holds the JSON, nothing else
    assert set(keys) == {robot, admin}
    assert keys[robot]["role"] == "robot"
    assert keys[robot]["name"] == "robot7"
    assert keys[robot]["prefix"].startswith("att_")
    assert keys[admin] | {"created_at": None} == {
        "id": admin,
        "role": "admin",
        "fleet": "north",
        "name": None,
        "prefix": keys[admin]["prefix"],
        "created_at": None,
        "revoked_at": None,
    }
    assert dt.datetime.fromisoformat(keys[robot]["revoked_at"]).tzinfo is not None
    assert dt.datetime.fromisoformat(keys[admin]["created_at"]).tzinfo is not None


def test_revoking_says_what_happened_and_twice_changes_nothing(attune: Attune) -> None:
    key_id = make_key(attune)
    first = attune("keys", "revoke", key_id)
    assert first.exit_code == 0, first.stderr
    assert f"Revoked {key_id}: its requests get 401 from now on." in first.stderr
    [listed] = json.loads(attune("keys", "list", "--json").stdout)
    revoked_at = listed["revoked_at"]
    assert revoked_at

    again = attune("keys", "revoke", key_id)
    assert again.exit_code == 0, again.stderr
    assert f"Key {key_id} was already revoked at {revoked_at}; nothing changed." in again.stderr
    assert "Revoked" not in again.stderr
    [still] = json.loads(attune("keys", "list", "--json").stdout)
    assert still["revoked_at"] == revoked_at  # the first revocation's time stays


def test_revoking_an_unknown_key_fails_with_a_sentence(attune: Attune) -> None:
    done = attune("keys", "revoke", "key_0000000000000000")
    assert done.exit_code == 2
    assert (
        "No key 'key_0000000000000000'; GET /v1/admin/keys and `attune keys list` show "
        "the ids." in done.stderr
    )
    assert "Traceback" not in done.stderr
    assert done.stdout == ""


def test_rebuilding_an_unknown_user_speaks_of_the_database_not_a_fleet(attune: Attune) -> None:
    done = attune("models", "rebuild", "ghost")
    assert done.exit_code == 2
    assert done.stderr.strip().splitlines()[-1] == "No user 'ghost' in this database."
    assert "fleet" not in done.stderr
    assert done.stdout == ""  # no summary line for a user that is not there
