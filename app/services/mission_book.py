"""The versions of the fleets' missions a worker has read (what learning reads of them is
immutable once stored, so cached for good), beside the deployment's default mission."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import missions as repo
from app.db.repositories.missions import MissionRow
from app.learning import Mission, NegotiationSpace, space_for
from app.learning.learners import TabularLearner
from app.learning.remap import Renames, remap_learner

__all__ = ["MissionBook", "Stored"]


@dataclass(frozen=True, slots=True)
class Stored:
    """A stored version: its mission, its layout, and the renames that led to it."""

    version: int
    mission: Mission
    space: NegotiationSpace
    renames: Renames


class MissionBook:
    """The stored versions this worker has read, by (fleet, version): a version never changes,
    so an entry never goes stale. Versions not stored (a fleet that has none yet uses the
    default) are not kept."""

    def __init__(self, default: Mission) -> None:
        self.default = default
        self._items: dict[tuple[str, int], Stored] = {}
        self._lock = threading.Lock()

    def get(self, session: Session, fleet: str, version: int) -> Stored:
        found = self._items.get((fleet, version))
        if found is not None:
            return found
        row = repo.get(session, fleet, version)
        if row is None:
            if version == 1 and repo.latest_version(session, fleet) is None:
                return Stored(1, self.default, space_for(self.default), Renames())
            raise LookupError(f"fleet {fleet!r} has no mission version {version}")
        stored = _stored(row)
        with self._lock:
            self._items[(fleet, version)] = stored
        return stored

    def carry(
        self, session: Session, fleet: str, learner: TabularLearner[Any], old: int, new: int
    ) -> TabularLearner[Any]:
        """``learner`` (laid out for version ``old`` of ``fleet``'s mission) carried to version
        ``new``, one version at a time: what still applies is kept, the rest dropped."""
        for version in range(old + 1, new + 1):
            target = self.get(session, fleet, version)
            learner = remap_learner(learner, target.mission, target.renames)
        return learner

    def display(self, session: Session, fleet: str, version: int) -> Mission:
        """The version's mission with its display fields (labels, time zone) as stored now:
        read anew each time, since a change of only those updates the version in place (the
        cached entries serve learning, which does not read them)."""
        row = repo.get(session, fleet, version)
        if row is None:
            return self.get(session, fleet, version).mission
        return Mission.from_dict(row.document, source=f"mission {row.fleet} v{row.version}")


def _stored(row: MissionRow) -> Stored:
    mission = Mission.from_dict(row.document, source=f"mission {row.fleet} v{row.version}")
    return Stored(
        row.version,
        mission,
        space_for(mission),
        Renames.from_dict(row.renames) if row.renames else Renames(),
    )
