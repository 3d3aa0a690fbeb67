"""The client's types hold a robot's code to the contract's values: ``mypy --strict`` fails on a
misspelt response, action kind, feedback or initiator, passes on the same code spelt right and
on the client README's examples, and the models still parse what a newer service may add.

mypy runs once, in a subprocess, on three files: the typos, the same code spelt right, and the
README's ``python`` blocks as one program (as tests/client/test_readme.py runs them).
"""

from __future__ import annotations

import re
import subprocess
import sys
from dataclasses import dataclass

import attune_client as a
import pytest

from tests.client.test_readme import python_blocks

GOOD = """\
from attune_client import Client, Decision, Outcome


def react(decision: Decision) -> Outcome:
    if decision.action.kind == "pass":
        return {"response": "none"}
    if decision.action.kind == "query_detail":
        return {"response": "answered", "detail": "tea"}
    return {"response": "accepted", "feedback": "positive"}


def report(attune: Client, episode_id: str, decision: Decision) -> None:
    attune.start_episode(
        "lin", event_id="e1", occurred_at="2026-11-22T15:10:00+08:00", situation="anything",
        initiator="human",
    )
    attune.report_outcome(episode_id, decision_id=decision.decision_id, **react(decision))
    attune.report_outcome(episode_id, decision_id=decision.decision_id, response="accepted")
    attune.send_feedback(episode_id, feedback_id="f1", feedback="negative")
"""

# Each line marked "# typo" must be the line of one of mypy's errors, and no other line.
BAD = """\
from attune_client import Client, Decision, Outcome


def react(decision: Decision) -> Outcome:
    if decision.action.kind == "perfrom":  # typo
        return {"response": "accepted"}
    return {"response": "acepted"}  # typo


def report(attune: Client, episode_id: str, decision: Decision) -> None:
    attune.start_episode(
        "lin", event_id="e1", occurred_at="2026-11-22T15:10:00+08:00", situation="anything",
        initiator="humans",  # typo
    )
    attune.report_outcome(episode_id, decision_id=decision.decision_id, response="acepted")  # typo
    attune.report_outcome(
        episode_id, decision_id=decision.decision_id, response="none", feedback="good",  # typo
    )
    attune.send_feedback(episode_id, feedback_id="f1", feedback="posittive")  # typo
"""

ERROR = re.compile(r"^(?P<file>[\w.]+):(?P<line>\d+): error: ", re.MULTILINE)


@dataclass(frozen=True)
class Checked:
    """What mypy said: the lines of its errors per file, and its whole output."""

    lines: dict[str, set[int]]
    output: str


@pytest.fixture(scope="module")
def checked(tmp_path_factory: pytest.TempPathFactory) -> Checked:
    """mypy --strict on the three files."""
    folder = tmp_path_factory.mktemp("typed")
    (folder / "good.py").write_text(GOOD, encoding="utf-8")
    (folder / "bad.py").write_text(BAD, encoding="utf-8")
    (folder / "readme.py").write_text("\n\n".join(python_blocks()), encoding="utf-8")
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "mypy",
            "--strict",
            "--no-error-summary",
            "--cache-dir",
            str(folder / ".mypy_cache"),
            "good.py",
            "bad.py",
            "readme.py",
        ],
        cwd=folder,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode in (0, 1), done.stdout + done.stderr  # 1: errors found, 2: mypy failed
    lines: dict[str, set[int]] = {"good.py": set(), "bad.py": set(), "readme.py": set()}
    for found in ERROR.finditer(done.stdout):
        lines[found["file"]].add(int(found["line"]))
    return Checked(lines, done.stdout)


def test_mypy_strict_fails_on_each_misspelt_value(checked: Checked) -> None:
    typos = {n for n, line in enumerate(BAD.splitlines(), 1) if line.endswith("# typo")}
    assert len(typos) == 6
    assert checked.lines["bad.py"] == typos, checked.output


def test_mypy_strict_passes_the_same_code_spelt_right(checked: Checked) -> None:
    assert checked.lines["good.py"] == set(), checked.output


def test_mypy_strict_passes_the_readme_examples(checked: Checked) -> None:
    assert checked.lines["readme.py"] == set(), checked.output


def test_a_value_a_newer_service_adds_still_parses() -> None:
    """Typed for the type checker only: at run time these fields take any string, as before."""
    decision = a.Decision.model_validate(
        {
            "decision_id": "dec_1",
            "action": {"kind": "dance", "service": "Music"},
            "expects": ["applauded", "accepted"],
            "probabilities": [{"action": {"kind": "dance"}, "p": 1.0}],
        }
    )
    kind: str = decision.action.kind  # the type checker holds it to ActionKind; not the parse
    assert kind == "dance"
    assert decision.expects == ["applauded", "accepted"]
    state = a.EpisodeState.model_validate(
        {"episode_id": "ep_1", "status": "open", "state": "LISTENING", "total_reward": 0.0}
    )
    name: str = state.state
    assert name == "LISTENING"
    with pytest.raises(ValueError, match="expected a string"):
        a.Action.model_validate({"kind": 3})
    with pytest.raises(ValueError, match="status"):  # checked as before
        a.EpisodeState.model_validate(
            {"episode_id": "ep_1", "status": "paused", "state": "END", "total_reward": 0.0}
        )
