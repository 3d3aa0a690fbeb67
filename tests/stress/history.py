"""A Jepsen-style history check: many robots write, every acknowledged write is recorded, and
afterwards the stored history and model must account for exactly those writes.

``Workload`` drives ``clients`` robots (threads), most of them on one hot user, with retries
after lost responses, duplicate sends (the same request twice at once) and conflicting resends
(the same client id with another body, which must be 409). Each robot records every write the
service acknowledged (2xx) in a ``History``. ``check_history`` then reads the service back
through the API and the database and returns its findings (an empty list: nothing lost, nothing
doubled): it is a function, so a test can assert it both ways, and one does, against a
deliberately broken update path.
"""

from __future__ import annotations

import json
import random
import threading
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from typing import Any

import httpx
from sqlalchemy import create_engine, select

from app.db.models import Decision, Episode, Feedback, JournalEntry, LearnerModel, User
from app.learning import Mission
from tests.support import commands, people
from tests.support.office import MISSION

SLOT_TIMES = ("09:30", "12:15", "15:10", "20:45")
INTERRUPTED: dict[str, Any] = {"interrupted": True}  # what ``Robot.send`` returns for one
OTHER_RESPONSE = {
    "accepted": "rejected",
    "rejected": "accepted",
    "terminated": "accepted",
    "answered": "terminated",
    "none": "human_request",
    "human_request": "none",
}


@dataclass(frozen=True)
class Ack:
    """One acknowledged write: who sent it, what, and what the service answered."""

    client: int
    kind: str  # "episode", "outcome" or "feedback"
    user_id: str
    key: str  # the client id: event_id, decision_id or "episode_id/feedback_id"
    body: str  # the request body, as JSON
    status: int
    replay: bool
    response: dict[str, Any]


@dataclass
class History:
    """What the robots saw: acknowledged writes, writes whose fate is unknown (in flight when
    the service died, retries exhausted), and everything that broke a rule on the spot."""

    acks: list[Ack] = field(default_factory=list)
    unknown: dict[str, str] = field(default_factory=dict)  # key -> kind
    anomalies: list[str] = field(default_factory=list)
    sent: set[str] = field(default_factory=set)  # every client id ever sent
    # Outcomes refused because a change of the fleet's mission interrupted their episode.
    interrupted: set[str] = field(default_factory=set)
    retried: Counter[int] = field(default_factory=Counter)  # 429 and 503 answers, by status
    lock: threading.Lock = field(default_factory=threading.Lock)

    def ack(self, ack: Ack) -> None:
        with self.lock:
            self.acks.append(ack)
            self.unknown.pop(ack.key, None)

    def note(self, text: str) -> None:
        with self.lock:
            self.anomalies.append(text)


class Paused(Exception):
    """The service is gone (killed); the robot waits for ``Workload.resume``."""


class Robot:
    """One client: its own key, seeded choices, and a record of what it was told."""

    def __init__(self, workload: Workload, n: int, key: str) -> None:
        self.w, self.n = workload, n
        self.rng = random.Random(workload.seed * 1000 + n)
        self.http = httpx.Client(
            base_url=workload.base_url, timeout=30.0, headers={"Authorization": f"Bearer {key}"}
        )

    def close(self) -> None:
        self.http.close()

    # -- sending ------------------------------------------------------------------------------
    def _once(self, url: str, body: dict[str, Any], timeout: float | None = None) -> httpx.Response:
        self.w.gate()
        kwargs: dict[str, Any] = {"json": body}
        if timeout is not None:
            kwargs["timeout"] = timeout
        return self.http.post(url, **kwargs)

    def send(
        self, kind: str, user_id: str, key: str, url: str, body: dict[str, Any]
    ) -> dict[str, Any] | None:
        """Send until acknowledged (retrying lost responses and 429/503), record the ack."""
        w = self.w
        with w.history.lock:
            w.history.sent.add(key)
        # One write in ten loses its first response (a timeout far shorter than the work):
        # the retry must be answered by an idempotent replay of what was stored.
        short = self.rng.random() < w.lost_response_rate
        for attempt in range(w.max_attempts):
            if time.monotonic() > w.deadline:
                break
            try:
                r = self._once(url, body, timeout=0.005 if short and attempt == 0 else None)
            except httpx.TransportError:
                with w.history.lock:
                    w.history.unknown.setdefault(key, kind)
                if w.paused.is_set():
                    w.resumed.wait(timeout=max(0.0, w.deadline - time.monotonic()))
                else:
                    time.sleep(0.02)
                continue
            if r.status_code in (429, 503):
                with w.history.lock:
                    w.history.retried[r.status_code] += 1
                time.sleep(min(2.0, float(r.headers.get("Retry-After", "1"))) / 10)
                continue
            if r.status_code >= 500:
                w.history.note(f"{kind} {key}: {r.status_code} {r.text[:200]}")
                continue
            if r.status_code == 409 and kind == "outcome" and "was interrupted" in r.text:
                # The fleet's mission changed while the episode was open: it is over.
                with w.history.lock:
                    w.history.interrupted.add(key)
                    w.history.unknown.pop(key, None)
                return INTERRUPTED
            if r.status_code >= 300:
                w.history.note(f"{kind} {key}: unexpected {r.status_code} {r.text[:200]}")
                with w.history.lock:
                    w.history.unknown.pop(key, None)
                return None
            out: dict[str, Any] = r.json()
            w.history.ack(
                Ack(
                    self.n,
                    kind,
                    user_id,
                    key,
                    json.dumps(body, sort_keys=True),
                    r.status_code,
                    r.headers.get("Idempotent-Replay") == "true",
                    out,
                )
            )
            return out
        with w.history.lock:
            w.history.unknown.setdefault(key, kind)
        return None

    def write(
        self,
        kind: str,
        user_id: str,
        key: str,
        url: str,
        body: dict[str, Any],
        clash: dict[str, Any],
    ) -> dict[str, Any] | None:
        """A write, sometimes sent twice at once, sometimes followed by a conflicting body."""
        w = self.w
        if self.rng.random() < w.duplicate_rate:
            twin = threading.Thread(target=self.send, args=(kind, user_id, key, url, body))
            twin.start()
            out = self.send(kind, user_id, key, url, body)
            twin.join(timeout=60)
        else:
            out = self.send(kind, user_id, key, url, body)
        if out is not None and self.rng.random() < w.conflict_rate:
            try:
                r = self._once(url, clash)
            except (httpx.TransportError, Paused):
                return out
            if r.status_code != 409 or r.json().get("error") != "Conflict":
                w.history.note(
                    f"{kind} {key}: a conflicting resend got {r.status_code} "
                    f"{r.text[:200]}, not 409 Conflict"
                )
        return out

    # -- the robot's behaviour ----------------------------------------------------------------
    def episode(self, k: int) -> bool:
        """One event and its negotiation to the end; False when the run must stop."""
        w = self.w
        user_id = w.hot_user if self.rng.random() < w.hot_share else self.rng.choice(w.users)
        event_id = f"c{self.n}-e{k}"
        situation = self.rng.choice(MISSION.situations)
        body: dict[str, Any] = {
            "event_id": event_id,
            "situation": situation,
            "robot_id": f"robot-{self.n}",
            "occurred_at": f"2026-11-{1 + k % 28:02d}T{self.rng.choice(SLOT_TIMES)}:00+08:00",
            "initiator": "robot",
            "request": None,
        }
        if self.rng.random() < 0.2:
            body.update(initiator="human", request={"service": "ProvideDrink", "detail": "tea"})
        other = [s for s in MISSION.situations if s != situation]
        clash = {**body, "situation": self.rng.choice(other)}
        ep = self.write("episode", user_id, event_id, f"/v1/users/{user_id}/episodes", body, clash)
        if ep is None:
            return False
        episode_id, decision = ep["episode_id"], ep["decision"]
        for _ in range(8):  # an episode has at most four visible steps
            if decision is None:
                break
            # A cooperative person: yes four times in five, asks for a drink half the time the
            # robot waits (naming tea half of those), smiles at one service in ten.
            said = people.answer(
                decision["action"],
                picky=False,
                rng=self.rng,
                yes=0.8,
                asks=0.5,
                precise=0.5,
                smiles=0.1,
                mission=w.mission,
            )
            sent = {"decision_id": decision["decision_id"], **said}
            conflicting = {
                "decision_id": sent["decision_id"],
                "response": OTHER_RESPONSE[sent["response"]],
            }
            out = self.write(
                "outcome",
                user_id,
                sent["decision_id"],
                f"/v1/episodes/{episode_id}/outcomes",
                sent,
                conflicting,
            )
            if out is None:
                return False
            if out is INTERRUPTED:
                return True  # on to the next event
            decision = out["decision"]
        if self.rng.random() < w.feedback_rate:
            fid = f"c{self.n}-f{k}"
            fb = {"feedback_id": fid, "feedback": self.rng.choice(["positive", "negative"])}
            clash_fb = {
                **fb,
                "feedback": "negative" if fb["feedback"] == "positive" else "positive",
            }
            if (
                self.write(
                    "feedback",
                    user_id,
                    f"{episode_id}/{fid}",
                    f"/v1/episodes/{episode_id}/feedback",
                    fb,
                    clash_fb,
                )
                is None
            ):
                return False
        return True

    def run(self) -> None:
        try:
            for k in range(self.w.episodes_per_client):
                if time.monotonic() > self.w.deadline or self.w.stopping.is_set():
                    return
                if not self.episode(k):
                    return
        except Exception as exc:  # a robot that dies is a finding, not a hang
            self.w.history.note(f"client {self.n} failed: {exc!r}")
        finally:
            self.close()


class Workload:
    """``clients`` robots, one key each, most of the traffic on ``hot_user``."""

    def __init__(
        self,
        base_url: str,
        keys: list[str],
        *,
        episodes_per_client: int = 5,
        hot_user: str = "hot",
        users: tuple[str, ...] = ("cold-1", "cold-2"),
        hot_share: float = 0.75,
        seed: int = 7,
        budget_s: float = 240.0,
        duplicate_rate: float = 0.1,
        conflict_rate: float = 0.1,
        lost_response_rate: float = 0.1,
        feedback_rate: float = 0.3,
        max_attempts: int = 50,
        mission: Mission = MISSION,
    ) -> None:
        self.base_url, self.keys = base_url, keys
        self.mission = mission  # the fleet's, as the robots answer questions under it
        self.episodes_per_client = episodes_per_client
        self.hot_user, self.users, self.hot_share = hot_user, list(users), hot_share
        self.seed, self.deadline = seed, time.monotonic() + budget_s
        self.duplicate_rate, self.conflict_rate = duplicate_rate, conflict_rate
        self.lost_response_rate, self.feedback_rate = lost_response_rate, feedback_rate
        self.max_attempts = max_attempts
        self.history = History()
        self.paused = threading.Event()  # set: the service is (about to be) down
        self.resumed = threading.Event()
        self.stopping = threading.Event()
        self._threads: list[threading.Thread] = []

    @property
    def all_users(self) -> list[str]:
        return [self.hot_user, *self.users]

    def gate(self) -> None:
        """Robots hold their next request while the service is being killed and restarted."""
        if self.paused.is_set():
            self.resumed.wait(timeout=max(0.0, self.deadline - time.monotonic()))

    def start(self) -> None:
        for n, key in enumerate(self.keys):
            t = threading.Thread(target=Robot(self, n, key).run, name=f"robot-{n}", daemon=True)
            t.start()
            self._threads.append(t)

    def join(self) -> None:
        for t in self._threads:
            t.join(timeout=max(1.0, self.deadline - time.monotonic() + 30))
        alive = [t.name for t in self._threads if t.is_alive()]
        if alive:
            self.history.note(f"robots still running after the deadline: {alive}")

    def run(self) -> History:
        self.start()
        self.join()
        return self.history

    def pause(self) -> None:
        self.resumed.clear()
        self.paused.set()

    def resume(self) -> None:
        self.paused.clear()
        self.resumed.set()


# -- the check ---------------------------------------------------------------------------------
@dataclass
class Snapshot:
    """One user as stored (database) and as served (API)."""

    episodes: list[Episode]
    decisions: list[Decision]
    feedback: list[Feedback]
    journal: list[JournalEntry]
    model: LearnerModel
    user: User
    traces: dict[str, dict[str, Any]]
    model_view: dict[str, Any]


def _snapshot(api: httpx.Client, database_url: str, user_id: str, fleet: str) -> Snapshot:
    engine = create_engine(database_url)
    try:
        with engine.connect() as conn:
            from sqlalchemy.orm import Session

            with Session(bind=conn) as s:
                user = s.scalars(
                    select(User).where(User.fleet == fleet, User.user_id == user_id)
                ).one()
                episodes = list(
                    s.scalars(
                        select(Episode).where(Episode.user_pk == user.id).order_by(Episode.seq)
                    )
                )
                ids = [e.id for e in episodes]
                decisions = (
                    list(
                        s.scalars(
                            select(Decision)
                            .where(Decision.episode_id.in_(ids))
                            .order_by(Decision.episode_id, Decision.position)
                        )
                    )
                    if ids
                    else []
                )
                feedback = (
                    list(s.scalars(select(Feedback).where(Feedback.episode_id.in_(ids))))
                    if ids
                    else []
                )
                journal = list(
                    s.scalars(
                        select(JournalEntry)
                        .where(JournalEntry.user_pk == user.id)
                        .order_by(JournalEntry.version, JournalEntry.id)
                    )
                )
                model = s.scalars(select(LearnerModel).where(LearnerModel.user_pk == user.id)).one()
    finally:
        engine.dispose()
    traces = {}
    cursor: str | None = None
    listed: list[str] = []
    for _ in range(1000):  # pages of the API's own listing
        params: dict[str, Any] = {
            "limit": 500,
            "fleet": fleet,
            **({"cursor": cursor} if cursor else {}),
        }
        page = api.get(f"/v1/users/{user_id}/episodes", params=params).json()
        listed += [item["episode_id"] for item in page["items"]]
        cursor = page["next_cursor"]
        if cursor is None:
            break
    for episode_id in listed:
        r = api.get(f"/v1/episodes/{episode_id}")
        traces[episode_id] = r.json() if r.status_code == 200 else {"status_code": r.status_code}
    view = api.get(f"/v1/users/{user_id}/model", params={"fleet": fleet}).json()
    return Snapshot(episodes, decisions, feedback, journal, model, user, traces, view)


def check_history(
    history: History,
    api: httpx.Client,
    database_url: str,
    users: list[str],
    initial_versions: dict[str, int],
    rebuild: bool = False,
    fleet: str = "default",
) -> list[str]:
    """Every finding that shows a lost, doubled or inconsistent write; [] when there is none.

    ``users`` are of ``fleet``, the fleet of the history's robots; ``api`` is an admin
    client; ``initial_versions`` the model versions before the run;
    with ``rebuild``, ``attune models rebuild`` of each user (``tests/support/commands.py``)
    must reproduce its stored model.
    Writes in ``history.unknown`` (in flight when the service died) may or may not be stored;
    if they are, the same rules hold for them.
    """
    findings = [f"during the run: {a}" for a in history.anomalies]
    by_key: dict[str, list[Ack]] = defaultdict(list)
    for ack in history.acks:
        by_key[ack.key].append(ack)

    # 1. Every acknowledgement of one client id tells the same story, and at most one of them
    #    was a first execution (the others are replays).
    for key, acks in by_key.items():
        if len({json.dumps(a.response, sort_keys=True) for a in acks}) > 1:
            findings.append(f"{acks[0].kind} {key}: acknowledged with different bodies")
        if sum(not a.replay for a in acks) > 1:
            findings.append(
                f"{acks[0].kind} {key}: executed {sum(not a.replay for a in acks)} "
                "times (more than one acknowledgement without Idempotent-Replay)"
            )

    for user_id in users:
        snap = _snapshot(api, database_url, user_id, fleet)
        findings += _check_user(user_id, snap, by_key, history, initial_versions[user_id])
        if rebuild:
            summary = commands.rebuild(database_url, user_id, fleet=fleet).summary
            if summary.get("identical") is not True:
                findings.append(
                    f"{user_id}: `models rebuild` does not reproduce the stored model: {summary}"
                )
    return findings


def _check_user(
    user_id: str, snap: Snapshot, by_key: dict[str, list[Ack]], history: History, initial: int
) -> list[str]:
    out: list[str] = []
    acks = [a[0] for a in by_key.values() if a[0].user_id == user_id]
    unknown = set(history.unknown)

    # 2. Episodes: each acknowledged one stored exactly once, under the acknowledged id; the
    #    only other stored ones are writes whose answer was lost; none was made up.
    stored_by_event = Counter(e.event_id for e in snap.episodes)
    for event_id, n in stored_by_event.items():
        if n > 1:
            out.append(f"{user_id}: event {event_id} stored {n} times")
    episodes = {e.event_id: e for e in snap.episodes}
    acked_episodes = {a.key: a for a in acks if a.kind == "episode"}
    for event_id, ack in acked_episodes.items():
        ep = episodes.get(event_id)
        if ep is None:
            out.append(
                f"{user_id}: acknowledged episode {event_id} "
                f"({ack.response['episode_id']}) is not stored (lost)"
            )
        elif ep.id != ack.response["episode_id"]:
            out.append(
                f"{user_id}: event {event_id} stored as {ep.id}, acknowledged as "
                f"{ack.response['episode_id']}"
            )
        elif ack.response["episode_id"] not in snap.traces:
            out.append(f"{user_id}: acknowledged episode {ep.id} is not listed by the API")
    for event_id, ep in episodes.items():
        if event_id not in acked_episodes and event_id not in unknown:
            what = "was never sent" if event_id not in history.sent else "was never acknowledged"
            out.append(f"{user_id}: stored episode {ep.id} (event {event_id}) {what}")
    if [e.seq for e in snap.episodes] != list(range(1, len(snap.episodes) + 1)):
        out.append(f"{user_id}: episode indexes are not 1..{len(snap.episodes)}")
    if snap.user.episode_count != len(snap.episodes):
        out.append(
            f"{user_id}: the user counts {snap.user.episode_count} episodes, "
            f"{len(snap.episodes)} are stored"
        )

    # 3. Outcomes: each acknowledged one stored once, as sent; nothing else answered but the
    #    roots of human-initiated episodes and writes whose answer was lost.
    decisions = {d.id: d for d in snap.decisions}
    if len(decisions) != len(snap.decisions):
        out.append(f"{user_id}: a decision id is stored twice")
    ep_by_id = {e.id: e for e in snap.episodes}
    acked_outcomes = {a.key: a for a in acks if a.kind == "outcome"}
    for decision_id, ack in acked_outcomes.items():
        d = decisions.get(decision_id)
        sent = json.loads(ack.body)
        if d is None or d.response is None:
            out.append(f"{user_id}: acknowledged outcome of {decision_id} is not stored (lost)")
        elif d.response != sent["response"] or d.outcome_response != ack.response:
            out.append(
                f"{user_id}: decision {decision_id} stores {d.response!r}, acknowledged "
                f"{sent['response']!r}"
            )
        nxt = ack.response.get("decision")
        if nxt is not None and nxt["decision_id"] not in decisions:
            out.append(
                f"{user_id}: decision {nxt['decision_id']} was sent to a robot but is not stored"
            )
    for d in snap.decisions:
        if d.response is None:
            continue
        root = d.position == 0 and d.forced and ep_by_id[d.episode_id].initiator == "human"
        if not root and d.id not in acked_outcomes and d.id not in unknown:
            out.append(
                f"{user_id}: decision {d.id} is answered ({d.response}) but no outcome "
                "was acknowledged for it"
            )
    positions: dict[str, list[int]] = defaultdict(list)
    for d in snap.decisions:
        positions[d.episode_id].append(d.position)
    for episode_id, pos in positions.items():
        if pos != list(range(len(pos))):
            out.append(f"{user_id}: episode {episode_id} has decisions at positions {pos}")
    draws = sorted(d.draw for d in snap.decisions if d.draw is not None)
    if draws != list(range(len(draws))) or snap.user.draws != len(draws):
        out.append(
            f"{user_id}: the seed stream has gaps or repeats ({len(draws)} draws, "
            f"user at {snap.user.draws})"
        )

    # 4. Feedback: each acknowledged one stored once; no other.
    fb_keys = Counter(f"{f.episode_id}/{f.feedback_id}" for f in snap.feedback)
    acked_fb = {a.key for a in acks if a.kind == "feedback"}
    for key in acked_fb:
        if fb_keys[key] != 1:
            out.append(f"{user_id}: acknowledged feedback {key} stored {fb_keys[key]} times")
    for key, n in fb_keys.items():
        if key not in acked_fb and key not in unknown:
            out.append(f"{user_id}: feedback {key} stored ({n}×) but never acknowledged")

    # 5. Model versions: contiguous, one per model-changing write, and as many as the writes
    #    the robots had acknowledged (plus, at most, those whose answer was lost) and the moves
    #    to a new version of the fleet's mission (each one version, a "mission" sample).
    versions = sorted({s.version for s in snap.journal})
    if versions != list(range(initial + 1, snap.model.version + 1)):
        missing = sorted(set(range(initial + 1, snap.model.version + 1)) - set(versions))
        out.append(
            f"{user_id}: model at version {snap.model.version} but the journal holds "
            f"{len(versions)} versions after {initial} (missing {missing[:10]})"
        )
    kinds_per_version: dict[int, set[str]] = defaultdict(set)
    for s in snap.journal:
        kinds_per_version[s.version].add(s.kind)
    if any(len(k) > 1 for k in kinds_per_version.values()):
        out.append(f"{user_id}: a model version mixes transitions and feedback")
    changing = _model_changing_writes(snap)
    if snap.model.version - initial != changing:
        out.append(
            f"{user_id}: model version went {initial} -> {snap.model.version}, but the "
            f"history holds {changing} model-changing writes"
        )
    acked_changing = _acked_model_changing(acks) + _moves(snap) + _staff_writes(snap)
    maybe = sum(1 for k in unknown if k not in by_key)
    if not acked_changing <= snap.model.version - initial <= acked_changing + maybe:
        out.append(
            f"{user_id}: the robots had {acked_changing} model-changing writes "
            f"acknowledged (+{maybe} unknown), the model moved "
            f"{snap.model.version - initial} versions: updates lost or doubled"
        )

    # 6. The model's counts equal the history: journal and learner (visits, via the API) both
    #    hold one sample per answered decision and per silent step.
    steps = sum(d.response is not None for d in snap.decisions) + sum(
        len(d.chain) for d in snap.decisions
    )
    journal = sum(s.kind == "transition" for s in snap.journal)
    if journal != steps:
        out.append(f"{user_id}: the journal holds {journal} transitions, the history {steps}")
    per_context: Counter[tuple[str, str]] = Counter()
    for t in snap.traces.values():
        if "decisions" not in t:
            out.append(f"{user_id}: an episode listed by the API cannot be read: {t}")
            continue
        ctx = (t["context"]["time_slot"], t["context"]["situation"])
        per_context[ctx] += sum(
            (d["response"] is not None) + len(d["chain"]) for d in t["decisions"]
        )
    visits: Counter[tuple[str, str]] = Counter()
    for c in snap.model_view.get("contexts", []):
        visits[(c["time_slot"], c["situation"])] += sum(
            a["visits"] for st in c["states"] for a in st["actions"]
        )
    if +visits != +per_context:
        diff = {
            k: (visits[k], per_context[k])
            for k in set(visits) | set(per_context)
            if visits[k] != per_context[k]
        }
        out.append(
            f"{user_id}: model visits differ from the history per context (visits, history): {diff}"
        )
    if snap.model_view.get("version") != snap.model.version:
        out.append(
            f"{user_id}: the API shows version {snap.model_view.get('version')}, "
            f"the database {snap.model.version}"
        )
    return out


def _model_changing_writes(snap: Snapshot) -> int:
    """Writes in the stored history that taught the model (one version each)."""
    n = 0
    by_episode: dict[str, list[Decision]] = defaultdict(list)
    for d in snap.decisions:
        by_episode[d.episode_id].append(d)
    for ep in snap.episodes:
        ds = by_episode[ep.id]
        if ep.initiator == "human":
            n += 1  # the request's root and silent steps
            ds = ds[1:]  # the root was answered by the start, not by an outcome
        elif ds and ds[0].chain:
            n += 1
        n += sum(d.response is not None for d in ds)
    return n + sum(
        s.kind in ("feedback", "mission", "correction", "lift")
        for s in {s.version: s for s in snap.journal}.values()
    )


def _moves(snap: Snapshot) -> int:
    """The moves of the user's model to a new version of the fleet's mission."""
    return len({s.version for s in snap.journal if s.kind == "mission"})


def _staff_writes(snap: Snapshot) -> int:
    """Corrections made and lifted by staff (one version each; the staff's own requests, not
    the robots', check them: see test_corrections_under_load)."""
    return len({s.version for s in snap.journal if s.kind in ("correction", "lift")})


def _acked_model_changing(acks: list[Ack]) -> int:
    n = 0
    for a in acks:
        if a.kind == "outcome":
            n += 1
        elif a.kind == "feedback":
            n += 1  # no reset happens in these runs: every feedback teaches
        elif json.loads(a.body)["initiator"] == "human" or a.response["decision"]["chain"]:
            n += 1
    return n
