"""The READMEs' examples run as written against a real ``attune serve``.

The client README's ``python`` code blocks are run in order, in one fresh interpreter, as the
README says they run: the only setting is what the README asks for, the environment variables
``ATTUNE_URL`` and ``ATTUNE_KEY`` (a robot key made with ``attune keys create``, as the README
shows).

The project README's five-minute tour: its ``sh`` blocks, pasted in order into one bash, as a
reader pastes them into the second terminal; only the service's address differs (the tests take
a free port), and ``./scripts/attune`` is this checkout's command line. What the tour says comes
out must: no answer refused, every episode closed, and the profile's sentence the one the README
quotes.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.support.live import LiveService, fresh_database

pytestmark = pytest.mark.live

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "clients" / "python" / "README.md"
BLOCK = re.compile(r"^```python\n(.*?)^```$", re.DOTALL | re.MULTILINE)
TOUR = ROOT / "README.md"
SH_BLOCK = re.compile(r"^```sh\n(.*?)^```$", re.DOTALL | re.MULTILINE)
ATTUNE = Path(sys.executable).with_name("attune")


def python_blocks() -> list[str]:
    return BLOCK.findall(README.read_text(encoding="utf-8"))


def test_the_readme_has_the_examples_it_promises() -> None:
    blocks = python_blocks()
    assert len(blocks) == 4  # quick start, errors, the outbox's flush, async
    text = README.read_text(encoding="utf-8")
    assert 'os.environ["ATTUNE_URL"]' in blocks[0]
    assert "ATTUNE_KEY" in text
    for outside in ("api-v1.md", "../shared", "algorithm.md", "paper.txt"):
        assert outside not in text
    assert "docs/api.md" in text


@pytest.fixture(params=["sqlite", "postgresql"])
def live(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[LiveService]:
    with (
        fresh_database(request.param, tmp_path) as url,
        LiveService(url, log_path=tmp_path / "serve.log") as service,
    ):
        yield service


def test_the_readme_examples_run(live: LiveService, tmp_path: Path) -> None:
    key = live.create_key("robot", name="robot7")  # attune keys create --role robot ...
    robot = tmp_path / "robot"
    robot.mkdir()  # the robot's working folder: the quick start's outbox goes there
    script = robot / "readme_examples.py"
    script.write_text("\n\n".join(python_blocks()), encoding="utf-8")
    env = {**os.environ, "ATTUNE_URL": live.url, "ATTUNE_KEY": key}
    done = subprocess.run(
        [sys.executable, script.name],
        cwd=robot,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stdout + done.stderr + live.log()

    # What the examples did, as the service saw it: two episodes of "lin", the quick start's
    # played to its end with its feedback, and the errors example refused as it expects.
    assert "first decision:" in done.stdout
    assert "outcome refused:" in done.stderr  # the errors example's ConflictError, logged
    assert (robot / "attune-outbox.db").is_file()
    headers = {"Authorization": f"Bearer {key}"}
    items = httpx.get(f"{live.url}/v1/users/lin/episodes", headers=headers, timeout=10).json()[
        "items"
    ]
    assert len(items) == 2
    traces = [
        httpx.get(
            f"{live.url}/v1/episodes/{item['episode_id']}", headers=headers, timeout=10
        ).json()
        for item in items
    ]
    [first] = [t for t in traces if t["event_id"] == "robot7-000123"]
    assert first["status"] == "closed"
    assert [f["feedback_id"] for f in first["feedback"]] == ["robot7-fb-000042"]
    for trace in traces:
        assert trace["episode_id"] in done.stdout  # the async example lists both


def tour() -> str:
    """The project README's five-minute tour (its text, up to the next section)."""
    text = TOUR.read_text(encoding="utf-8")
    return text.split("## Five-minute tour", 1)[1].split("\n## ", 1)[0]


def tour_blocks() -> list[str]:
    return SH_BLOCK.findall(tour())


def test_the_tour_has_what_the_reader_pastes() -> None:
    blocks = tour_blocks()
    assert len(blocks) == 6  # the key, the helpers, the first event, Mrs. Lin, the look, staff
    assert sum(b.count("URL=http://127.0.0.1:8000") for b in blocks) == 1
    # Which answer fits which decision is a table to choose from, not lines to paste.
    assert not any(b.lstrip().startswith("answer ") for b in blocks)
    table = [line for line in tour().splitlines() if line.startswith("| `")]
    kinds = {"initiate", "perform", "pass", "query_type", "query_detail"}
    assert kinds <= {k for line in table for k in re.findall(r"`(\w+)`", line.split("|")[1])}


def _quoted_sentence() -> str:
    """The profile's sentence as the tour quotes it (one line, as the service sends it)."""
    text = " ".join(tour().split())
    found = re.search(r'in a sentence for the staff: "([^"]+)"', text)
    assert found is not None
    return found.group(1)


@pytest.fixture
def served(tmp_path: Path) -> Iterator[LiveService]:
    """The tour's service: ``attune serve`` on SQLite, as ``./scripts/attune serve`` runs it."""
    with (
        fresh_database("sqlite", tmp_path) as url,
        LiveService(url, log_path=tmp_path / "serve.log") as service,
    ):
        yield service


def test_the_tour_runs_as_written(served: LiveService, tmp_path: Path) -> None:
    folder = tmp_path / "clone"  # the reader's clone: ./scripts/attune is this checkout's
    (folder / "scripts").mkdir(parents=True)
    shim = folder / "scripts" / "attune"
    shim.write_text(f'#!/bin/sh\nexec "{ATTUNE}" "$@"\n', encoding="utf-8")
    shim.chmod(0o755)
    script = "\n".join(tour_blocks()).replace("http://127.0.0.1:8000", served.url)
    done = subprocess.run(
        ["bash"],
        input=script,
        cwd=folder,
        env={**served.env, "ATTUNE_KEY": "", "STAFF_KEY": ""},
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    said = done.stderr.splitlines()
    refused = [
        line
        for line in said
        if not line.startswith(("robot: ", "episode closed, total reward ", "Created "))
    ]
    assert refused == [], done.stderr + served.log()  # step prints an error's name and detail
    first = next(line for line in tour().splitlines() if line.startswith("# robot: "))
    assert said[1] == first.removeprefix("# ").split("  ")[0]  # after the robot key's line
    assert sum(line.startswith("episode closed") for line in said) == 31

    key = served.create_key("robot")
    headers = {"Authorization": f"Bearer {key}"}
    profile = httpx.get(f"{served.url}/v1/users/lin/profile", headers=headers, timeout=10).json()
    assert profile["episodes"] == 31
    assert profile["open_episodes"] == 0
    [stretch] = [
        c
        for c in profile["contexts"]
        if (c["time_slot"], c["situation"]) == ("afternoon", "stretching")
    ]
    assert stretch["summary"] == _quoted_sentence()
    corrections = {c["correction_id"] for c in profile["corrections"]}
    assert corrections == {"lin-1", "lin-2"}
