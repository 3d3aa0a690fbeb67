"""What every use case needs besides the session: settings, the missions, and the learner cache."""

from __future__ import annotations

import functools
import hashlib
import json
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import BaseModel
from sqlalchemy.orm import Session

from app.learning import Mission, NegotiationSpace, load_mission, office_mission, space_for
from app.learning.learners import TabularLearner
from app.settings import Settings

from .mission_book import MissionBook

__all__ = [
    "KeyCache",
    "LearnerCache",
    "Principal",
    "ServiceContext",
    "after_commit",
    "body_hash",
    "rng_for",
]


@dataclass(frozen=True, slots=True)
class Principal:
    """Who is calling: the key's id, role and fleet.

    Roles: a ``robot`` serves its fleet's users; the ``staff`` of a fleet also look after them
    (their models, history and audit log; reset, export, import, delete); an ``admin`` runs the
    deployment and sees every fleet.
    """

    key_id: str
    role: str
    fleet: str

    @property
    def is_admin(self) -> bool:
        return self.role == "admin"

    @property
    def manages(self) -> bool:
        """May reset, export, import and delete users, and read the audit log: staff (of their
        own fleet) and admins."""
        return self.role in ("staff", "admin")

    def sees(self, fleet: str) -> bool:
        """Whether the caller may see the users of ``fleet``."""
        return self.is_admin or fleet == self.fleet


class KeyCache:
    """The keys a worker authenticated lately, by digest, each kept ``seconds`` (0: none).

    A key revoked elsewhere (the command line, another worker) keeps working in this worker
    for at most ``seconds`` after it was last read from the database; a revocation made in
    this worker drops it at once (:meth:`drop`). Unknown keys are not kept. Thread-safe enough:
    the dict's single operations are atomic, and a race only re-reads a key.
    """

    def __init__(
        self, seconds: float, clock: Callable[[], float] = time.monotonic, size: int = 10_000
    ) -> None:
        self.seconds, self.clock, self.size = seconds, clock, size
        self._items: dict[str, tuple[Principal, float]] = {}

    def get(self, digest: str) -> Principal | None:
        item = self._items.get(digest)
        if item is None:
            return None
        if self.clock() >= item[1]:
            self._items.pop(digest, None)
            return None
        return item[0]

    def put(self, digest: str, principal: Principal) -> None:
        if self.seconds <= 0:
            return
        if len(self._items) >= self.size:
            self._items.clear()  # a flood of distinct keys: start over rather than grow
        self._items[digest] = (principal, self.clock() + self.seconds)

    def drop(self, key_id: str) -> None:
        for digest, (principal, _) in list(self._items.items()):
            if principal.key_id == key_id:
                self._items.pop(digest, None)


class LearnerCache:
    """Decoded learners by user, tagged with the model version they hold (an LRU).

    A writer *takes* the entry (so no one else sees it while it changes) and puts the updated
    learner back only after its transaction commits; a rollback simply leaves the entry out, and
    the next request decodes the stored document. With several workers each process has its own
    cache, and the version tag keeps it honest.
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self._items: OrderedDict[int, tuple[int, TabularLearner[Any]]] = OrderedDict()
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def take(self, user_pk: int, version: int) -> TabularLearner[Any] | None:
        with self._lock:
            item = self._items.pop(user_pk, None)
            if item is not None and item[0] == version:
                self.hits += 1
                return item[1]
            self.misses += 1
            return None

    def put(self, user_pk: int, version: int, learner: TabularLearner[Any]) -> None:
        if self.size <= 0:
            return
        with self._lock:
            self._items[user_pk] = (version, learner)
            self._items.move_to_end(user_pk)
            while len(self._items) > self.size:
                self._items.popitem(last=False)

    def drop(self, user_pk: int) -> None:
        with self._lock:
            self._items.pop(user_pk, None)


@dataclass
class ServiceContext:
    """``mission`` is the deployment's default mission (``ATTUNE_MISSION_PATH`` or the built-in
    office mission): a fleet gets it as its version 1. Every fleet's own versions are read
    through ``missions``."""

    settings: Settings
    mission: Mission
    space: NegotiationSpace
    cache: LearnerCache
    keys: KeyCache
    missions: MissionBook

    @classmethod
    def from_settings(cls, settings: Settings) -> ServiceContext:
        mission = load_mission(settings.mission_path) if settings.mission_path else office_mission()
        return cls(
            settings,
            mission,
            space_for(mission),
            LearnerCache(settings.model_cache_size),
            KeyCache(settings.key_cache_seconds),
            MissionBook(mission),
        )


def rng_for(seed: int, seed_key: str, draw: int) -> np.random.Generator:
    """The generator of a user's ``draw``-th decision: deployment seed, the user's seed key
    (``fleet/user_id``; the user id for users made before fleets had ids of their own), and
    the decision's position.

    Deriving it per decision (instead of carrying a generator's state) lets any worker draw the
    next decision and lets ``attune models rebuild`` redraw every past one.
    """
    return np.random.Generator(
        np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(*_seed_words(seed_key), draw)))
    )


@functools.lru_cache(maxsize=65536)
def _seed_words(seed_key: str) -> tuple[int, int, int, int]:
    """Four 32-bit words of the SHA-256 of a seed key (the user's part of the spawn key)."""
    digest = hashlib.sha256(seed_key.encode("utf-8")).digest()
    a, b, c, d = (int.from_bytes(digest[i : i + 4], "little") for i in range(0, 16, 4))
    return a, b, c, d


def body_hash(model: BaseModel) -> str:
    """A fingerprint of a request body as validated (so key order and spacing don't matter)."""
    doc = model.model_dump(mode="json")
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def after_commit(session: Session, callback: Callable[[], None]) -> None:
    """Run ``callback`` once the session's transaction has committed (never on rollback)."""
    session.info.setdefault("after_commit", []).append(callback)
