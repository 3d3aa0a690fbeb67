"""A model imported onto a user with a shorter history keeps its clock: the learner's episode
index never runs backwards, and the user's model still rebuilds exactly."""

from __future__ import annotations

import json

from fastapi.testclient import TestClient
from typer.testing import CliRunner

from app.cli import app as cli
from app.db.models import Episode
from app.db.session import Database
from app.settings import Settings
from tests.support import people
from tests.support.episodes import report, start
from tests.support.rows import user_pk


def _play(robot: TestClient, user: str, n: int, prefix: str) -> None:
    for i in range(n):
        ep = start(robot, user, f"{prefix}{i}")
        decision = ep["decision"]
        while decision is not None:  # a person who wants nothing
            decision = report(
                robot,
                ep["episode_id"],
                decision["decision_id"],
                **people.answer(decision["action"], need=None),
            )["decision"]


def test_imported_model_keeps_its_clock(
    robot: TestClient, admin: TestClient, db: Database, settings: Settings
) -> None:
    _play(robot, "veteran", 12, "v")
    doc = admin.get("/v1/users/veteran/model/export").json()
    _play(robot, "newcomer", 2, "n")
    assert admin.put("/v1/users/newcomer/model", json=doc).status_code == 200
    view = robot.get("/v1/users/newcomer/model").json()
    since = [a["since_last"] for c in view["contexts"] for s in c["states"] for a in s["actions"]]
    assert min(since) >= 1  # the imported model's clock did not run backwards

    _play(robot, "newcomer", 3, "m")
    with db.transaction(write=False) as session:
        rows = (
            session.query(Episode)
            .filter_by(user_pk=user_pk(session, "newcomer"))
            .order_by(Episode.seq)
            .all()
        )
        learner_index = [(e.seq, e.learner_episode) for e in rows]
    assert [s for s, _ in learner_index] == [1, 2, 3, 4, 5]
    assert [e for _, e in learner_index][2:] == [13, 14, 15]  # after the 12 imported episodes

    result = CliRunner().invoke(
        cli,
        ["models", "rebuild", "newcomer"],
        env={"ATTUNE_DATABASE_URL": settings.database_url, "ATTUNE_SEED": "0"},
    )
    assert result.exit_code == 0, result.output
    summary = json.loads(next(line for line in result.output.splitlines() if line.startswith("{")))
    assert summary["identical"] is True
