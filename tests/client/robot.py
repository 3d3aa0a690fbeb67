"""A simulated robot for the outbox acceptance test: a separate process that serves a few
people through ``attune_client.Client`` with an outbox file, and keeps a journal.

Run: ``python robot.py --url URL --key KEY --dir DIR [--episodes N]`` (N per person). In
``DIR`` it keeps ``outbox.db`` (the client's outbox), ``state.json`` (what it is doing,
replaced atomically) and ``journal.jsonl`` (every report it makes, in order, written before the
call; and what became of it). While a file ``hold`` exists there, it waits between rounds (so
a test can stop the service at a known moment).

It can be killed at any moment and started again with the same arguments: it picks up its
state, redoes the one call the journal shows unfinished (the service or the outbox answers a
repeat as the same report), and goes on. It exits 0 when it has played every episode and
nothing is left in its outbox.

Each round, every person gets one action: an outcome for the current decision, a smile
(feedback) while an outcome waits in the outbox, a last feedback after an episode ended, or a
new event. While the service is out of reach, new events fail (the robot falls back to its own
default, and the person may say a late word about an earlier episode: more feedback) and
reports are queued.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import httpx
from attune_client import (
    APIConnectionError,
    Client,
    Decision,
    EpisodeStarted,
    FeedbackResult,
    OutcomeResult,
    Queued,
)
from attune_client._retry import Backoff

from tests.support.people import (
    cooperative,  # the repository's root is on the path (editable install)
)

USERS = ("ana", "ben", "cy")
SMILES = 2  # feedback a person gives while the robot waits for an outcome to be delivered
LATE = 3  # late feedback a person may give on an earlier episode while the robot is offline
EVENT_TIME = dt.datetime.fromisoformat("2026-11-22T15:10:00+08:00")


class Robot:
    def __init__(self, client: Client, folder: Path, episodes: int) -> None:
        self.client, self.folder, self.episodes = client, folder, episodes
        self.state_path = folder / "state.json"
        self.journal_path = folder / "journal.jsonl"
        self.state: dict[str, Any] = {
            "done": 0,
            "users": {
                u: {
                    "next": 0,
                    "episode_id": None,
                    "event": None,
                    "decision": None,
                    "waiting": None,
                    "smiles": 0,
                    "final": False,
                    "step": 0,
                    "closed": [],
                }
                for u in USERS
            },
        }
        if self.state_path.exists():
            self.state = json.loads(self.state_path.read_text())
        journal = self._journal()
        self.intents = [line for line in journal if line["type"] == "intent"]
        self.run = 1 + sum(1 for line in journal if line["type"] == "boot")

    # -- persistence ---------------------------------------------------------------------------
    def _journal(self) -> list[dict[str, Any]]:
        if not self.journal_path.exists():
            return []
        lines = []
        for raw in self.journal_path.read_text().splitlines():
            try:
                lines.append(json.loads(raw))
            except json.JSONDecodeError:  # a line cut short by a kill
                continue
        return lines

    def write(self, **line: Any) -> None:
        with open(self.journal_path, "a") as journal:
            journal.write(json.dumps({"run": self.run, "t": round(time.time(), 3), **line}) + "\n")
            journal.flush()
            os.fsync(journal.fileno())

    def save(self) -> None:
        tmp = self.state_path.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.state))
        os.replace(tmp, self.state_path)

    # -- doing ---------------------------------------------------------------------------------
    def act(self, op: str, user: str, **args: Any) -> None:
        """Journal the intent, make the call, record what became of it."""
        i = len(self.intents)
        intent = {"type": "intent", "i": i, "op": op, "user": user, "args": args}
        self.write(**intent)
        self.intents.append(intent)
        self.perform(intent)

    def perform(self, intent: dict[str, Any]) -> None:
        op, user, args = intent["op"], intent["user"], intent["args"]
        person = self.state["users"][user]
        status: str
        if op == "start":
            try:
                started = self.client.start_episode(user, **args)
            except APIConnectionError:
                status = "offline"  # the robot serves this event by its own default
            else:
                status = "replayed" if started.replayed else "sent"
                self.on_started(user, started, int(args["event_id"].rsplit("-", 1)[1]))
        elif op == "outcome":
            result = self.client.report_outcome(**args)
            status = self.on_outcome(user, args, result)
        else:
            feedback = self.client.send_feedback(**args)
            assert isinstance(feedback, FeedbackResult | Queued)
            status = "queued" if isinstance(feedback, Queued) else "sent"
            tag = args["feedback_id"].rsplit("-", 1)[1]
            if tag == "end":
                person["closed"].append([person["episode_id"], person["event"], 0])
                person["final"] = False
                person["episode_id"] = None
            elif tag.startswith("late"):
                for closed in person["closed"]:
                    if closed[0] == args["episode_id"]:
                        closed[2] = int(tag[4:])
            else:  # a smile: "s1", "s2"...
                person["smiles"] = int(tag[1:])
        self.state["done"] = intent["i"] + 1
        self.save()
        self.write(
            type="result",
            i=intent["i"],
            op=op,
            status=status,
            key=args.get("decision_id") or args.get("feedback_id"),
        )

    def on_started(self, user: str, started: EpisodeStarted, event: int) -> None:
        person = self.state["users"][user]
        person.update(
            episode_id=started.episode_id,
            event=event,
            step=0,
            decision=started.decision.model_dump(mode="json") if started.decision else None,
            waiting=None,
            smiles=0,
            final=False,
            next=event + 1,
        )

    def on_outcome(self, user: str, args: dict[str, Any], result: OutcomeResult | Queued) -> str:
        person = self.state["users"][user]
        person["decision"] = None
        if isinstance(result, Queued):
            person["waiting"] = args
            person["smiles"] = 0
            return "queued"
        self.on_answer(user, result)
        return "replayed" if result.replayed else "sent"

    def on_answer(self, user: str, result: OutcomeResult) -> None:
        person = self.state["users"][user]
        person["waiting"] = None
        person["step"] += 1
        if result.decision is None:
            person["final"] = True
        else:
            person["decision"] = result.decision.model_dump(mode="json")

    def learn_deliveries(self) -> None:
        """What the outbox delivered: the next decisions of the episodes that waited."""
        waiting = {
            p["waiting"]["decision_id"]: u for u, p in self.state["users"].items() if p["waiting"]
        }
        if not waiting:
            return
        report = self.client.flush()
        if report.rejected:
            self.write(type="rejected", keys=[p.key for p, _ in report.rejected])
            sys.exit(3)
        for entry, result in report.delivered:
            user = waiting.pop(entry.key, None)
            if user is not None and isinstance(result, OutcomeResult):
                self.on_answer(user, result)
        if not waiting:
            self.save()
            return
        pending = {p.key for p in self.client.pending()}
        for key, user in waiting.items():
            if key not in pending:  # delivered before a restart: ask again (a replay)
                again = self.client.report_outcome(**self.state["users"][user]["waiting"])
                if isinstance(again, OutcomeResult):
                    self.on_answer(user, again)
        self.save()

    def round(self) -> None:
        self.learn_deliveries()
        for user in USERS:
            person = self.state["users"][user]
            if person["decision"] is not None:
                decision = Decision.model_validate(person["decision"])
                self.act(
                    "outcome",
                    user,
                    episode_id=person["episode_id"],
                    decision_id=decision.decision_id,
                    **cooperative(decision.action, person["event"] + person["step"]),
                )
            elif person["waiting"] is not None:
                if person["smiles"] < SMILES:
                    self.act(
                        "feedback",
                        user,
                        episode_id=person["episode_id"],
                        feedback_id=f"{person['waiting']['decision_id']}-s{person['smiles'] + 1}",
                        feedback="positive",
                    )
            elif person["final"]:
                self.act(
                    "feedback",
                    user,
                    episode_id=person["episode_id"],
                    feedback_id=f"robot7-{user}-{person['event']:04d}-end",
                    feedback="negative" if person["event"] % 4 == 3 else "positive",
                )
            elif person["next"] < self.episodes:
                n = person["next"]
                self.act(
                    "start",
                    user,
                    event_id=f"robot7-{user}-{n:04d}",
                    occurred_at=(EVENT_TIME + dt.timedelta(minutes=n)).isoformat(),
                    situation=("arriving", "working", "stretching")[n % 3],
                    robot_id="robot7",
                )
                if person["episode_id"] is None:  # offline: a late word on an earlier episode
                    for episode_id, event, late in person["closed"]:
                        if late < LATE:
                            self.act(
                                "feedback",
                                user,
                                episode_id=episode_id,
                                feedback_id=f"robot7-{user}-{event:04d}-late{late + 1}",
                                feedback="positive",
                            )
                            break

    def finished(self) -> bool:
        return all(
            p["next"] >= self.episodes and p["episode_id"] is None
            for p in self.state["users"].values()
        )

    def resume(self) -> None:
        """Redo the call the journal shows begun but not finished (killed in between)."""
        if self.intents and self.intents[-1]["i"] >= self.state["done"]:
            self.write(type="redo", i=self.intents[-1]["i"])
            self.perform(self.intents[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--url", required=True)
    parser.add_argument("--key", required=True)
    parser.add_argument("--dir", required=True, type=Path)
    parser.add_argument("--episodes", type=int, default=8, help="episodes per person")
    parser.add_argument("--pause", type=float, default=0.02, help="seconds between rounds")
    parser.add_argument("--deadline", type=float, default=150.0)
    opts = parser.parse_args()
    client = Client(
        opts.url,
        opts.key,
        timeout=httpx.Timeout(3.0, connect=1.0),
        max_retries=2,
        outbox=opts.dir / "outbox.db",
    )
    client._backoff = Backoff(initial=0.05, maximum=0.2)
    robot = Robot(client, opts.dir, opts.episodes)
    robot.write(type="boot", pid=os.getpid(), pending=len(client.pending()))
    robot.resume()
    stop = time.monotonic() + opts.deadline
    while not (robot.finished() and not client.pending()):
        if time.monotonic() > stop:
            robot.write(type="timeout")
            return 4
        if (opts.dir / "hold").exists():
            robot.write(type="held")
            while (opts.dir / "hold").exists() and time.monotonic() < stop:
                time.sleep(0.01)
        if robot.finished():
            robot.learn_deliveries()
            client.flush()
        else:
            robot.round()
        time.sleep(opts.pause)
    robot.write(type="done", rejected=len(client.rejected()))
    client.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
