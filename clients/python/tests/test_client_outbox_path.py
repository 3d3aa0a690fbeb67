"""An outbox path that cannot be used raises ``OutboxError`` naming the path and saying why,
from ``Client`` and ``AsyncClient`` alike (the client does not create missing folders)."""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import attune_client as a
import pytest
from attune_client_fakes import BASE_URL, KEY


def open_sync(path: Path) -> None:
    a.Client(BASE_URL, KEY, outbox=path).close()


def open_async(path: Path) -> None:
    a.AsyncClient(BASE_URL, KEY, outbox=path)  # the outbox opens in the constructor


OPENERS = [pytest.param(open_sync, id="Client"), pytest.param(open_async, id="AsyncClient")]
Opener = Callable[[Path], None]


def refused(opener: Opener, path: Path) -> a.OutboxError:
    with pytest.raises(a.OutboxError) as caught:
        opener(path)
    error = caught.value
    assert isinstance(error, a.AttuneError)
    assert error.path == str(path)
    assert repr(str(path)) in str(error)  # the message names the path
    assert isinstance(error.__cause__, sqlite3.Error)
    return error


@pytest.mark.parametrize("opener", OPENERS)
def test_a_missing_folder_is_not_created(opener: Opener, tmp_path: Path) -> None:
    path = tmp_path / "robot7" / "outbox.db"
    error = refused(opener, path)
    assert str(error) == (
        f"Cannot open the outbox {str(path)!r}: its folder {tmp_path / 'robot7'} "
        "does not exist (the client does not create folders)."
    )
    assert not (tmp_path / "robot7").exists()


@pytest.mark.parametrize("opener", OPENERS)
def test_a_relative_path_names_the_folder_it_means(
    opener: Opener, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    error = refused(opener, Path("state") / "outbox.db")
    assert f"its folder {tmp_path / 'state'} does not exist" in str(error)


@pytest.mark.parametrize("opener", OPENERS)
def test_a_folder_or_a_file_in_place_of_a_folder(opener: Opener, tmp_path: Path) -> None:
    assert "that is a folder; give the path of a file in it" in str(refused(opener, tmp_path))
    plain = tmp_path / "notes.txt"
    plain.write_text("not a folder\n")
    assert f"{plain} is not a folder" in str(refused(opener, plain / "outbox.db"))


@pytest.mark.parametrize("opener", OPENERS)
def test_a_file_that_is_not_an_outbox(opener: Opener, tmp_path: Path) -> None:
    path = tmp_path / "outbox.db"
    path.write_bytes(b"this is no SQLite database, whatever its name says" * 40)
    assert "file is not a database" in str(refused(opener, path))
    assert path.read_bytes().startswith(b"this is no SQLite")  # left as it was


@pytest.mark.parametrize("opener", OPENERS)
def test_an_existing_folder_gets_the_file(opener: Opener, tmp_path: Path) -> None:
    opener(tmp_path / "outbox.db")
    assert (tmp_path / "outbox.db").is_file()


# -- a folder the robot's user may not write in ------------------------------------------------
# Root writes in any folder, whatever its mode: as root, the check runs in a child process whose
# root has lost the capabilities that override file permissions (util-linux's setpriv).
CHECK = """
import json, sys
import attune_client as a
found = {}
for name in ("Client", "AsyncClient"):
    try:
        getattr(a, name)("http://attune.test", "att_key", outbox=sys.argv[1])
    except a.OutboxError as exc:
        found[name] = [exc.path, str(exc)]
print(json.dumps(found))
"""
NO_OVERRIDE = ["setpriv", "--bounding-set=-dac_override,-dac_read_search,-fowner"]


@pytest.fixture
def locked_folder(tmp_path: Path) -> Iterator[Path]:
    """A folder that its owner can enter but not write in."""
    folder = tmp_path / "locked"
    folder.mkdir(mode=0o555)
    yield folder
    folder.chmod(0o755)


def open_in_locked(path: Path) -> dict[str, Any]:
    if os.geteuid() != 0:
        found = {}
        for name, opener in (("Client", open_sync), ("AsyncClient", open_async)):
            with pytest.raises(a.OutboxError) as caught:
                opener(path)
            found[name] = [caught.value.path, str(caught.value)]
        return found
    if shutil.which("setpriv") is None:
        pytest.fail(
            "Running as root, this test needs setpriv (util-linux) to drop root's "
            "permission override.",
            pytrace=False,
        )
    done = subprocess.run(
        [*NO_OVERRIDE, sys.executable, "-c", CHECK, str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    result: dict[str, Any] = json.loads(done.stdout)
    return result


def test_a_folder_that_is_not_writable(locked_folder: Path) -> None:
    path = locked_folder / "outbox.db"
    found = open_in_locked(path)
    expected = (
        f"Cannot open the outbox {str(path)!r}: its folder {locked_folder} is not "
        "writable (the outbox keeps journal files beside it)."
    )
    assert found == {"Client": [str(path), expected], "AsyncClient": [str(path), expected]}
    assert not path.exists()
