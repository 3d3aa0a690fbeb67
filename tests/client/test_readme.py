"""The client README's examples run as written against a real ``attune serve``.

Its ``python`` code blocks are run in order, in one fresh interpreter, as the README says they
run: the only setting is what the README asks for, the environment variables ``ATTUNE_URL``
and ``ATTUNE_KEY`` (a robot key made with ``attune keys create``, as the README shows).
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

README = Path(__file__).resolve().parents[2] / "clients" / "python" / "README.md"
BLOCK = re.compile(r"^```python\n(.*?)^```$", re.DOTALL | re.MULTILINE)


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
