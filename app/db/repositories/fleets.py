"""A fleet's own settings (``fleet_settings``): a fleet without a row has the defaults."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass

from sqlalchemy import select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from ..models import FleetSettings
from ._rows import columns, conn, record, table

__all__ = ["FleetSettingsRow", "get", "set_prior"]


@dataclass(slots=True)
class FleetSettingsRow:
    fleet: str
    prior_enabled: bool
    updated_at: dt.datetime
    updated_by: str | None


_settings = table(FleetSettings)


def get(session: Session, fleet: str) -> FleetSettingsRow | None:
    return record(
        FleetSettingsRow,
        conn(session)
        .execute(select(*columns(_settings, FleetSettingsRow)).where(_settings.c.fleet == fleet))
        .first(),
    )


def set_prior(
    session: Session, fleet: str, *, enabled: bool, now: dt.datetime, actor: str | None
) -> None:
    """Turn the fleet's prior on or off (the row is made when missing)."""
    c = conn(session)
    dialect = postgresql if c.dialect.name == "postgresql" else sqlite
    stmt = dialect.insert(_settings).values(
        fleet=fleet, prior_enabled=enabled, updated_at=now, updated_by=actor
    )
    c.execute(
        stmt.on_conflict_do_update(
            index_elements=["fleet"],
            set_={"prior_enabled": enabled, "updated_at": now, "updated_by": actor},
        )
    )
