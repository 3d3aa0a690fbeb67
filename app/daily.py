"""A time of day on a clock of a time zone (``ATTUNE_RETENTION_AT="03:30 Europe/London"``), and
the next moment that clock shows it. Standard library only: the settings read it."""

from __future__ import annotations

import datetime as dt
import functools
import re
import zoneinfo
from dataclasses import dataclass

__all__ = ["DailyTime"]

_TEXT = re.compile(r"^(\d{1,2}):(\d{2})(?:\s+(\S+))?$")
_DAY = dt.timedelta(days=1)


@functools.cache
def _zones() -> frozenset[str]:
    return frozenset(zoneinfo.available_timezones())


@dataclass(frozen=True, slots=True)
class DailyTime:
    """``at`` (hours and minutes) on the clocks of ``zone`` (an IANA name; UTC by default)."""

    at: dt.time
    zone: str = "UTC"

    @classmethod
    def parse(cls, text: str) -> DailyTime | None:
        """``"03:30"`` (UTC) or ``"03:30 Europe/London"``; an empty text is ``None`` (no time).
        A ``ValueError`` with a sentence otherwise."""
        text = text.strip()
        if not text:
            return None
        found = _TEXT.match(text)
        hour, minute = (int(found[1]), int(found[2])) if found else (-1, -1)
        if found is None or not (0 <= hour <= 23 and 0 <= minute <= 59):
            raise ValueError(
                "retention_at must be a time of day as HH:MM (00:00 to 23:59), optionally "
                "followed by an IANA time zone name: 03:30 or 03:30 Europe/London."
            )
        zone = found[3] or "UTC"
        if zone not in _zones():
            raise ValueError(
                f"retention_at: {zone!r} is not an IANA time zone name (such as Europe/London "
                "or UTC)."
            )
        return cls(dt.time(hour, minute), zone)

    def __str__(self) -> str:
        return f"{self.at:%H:%M} {self.zone}"

    def next_after(self, moment: dt.datetime) -> dt.datetime:
        """The first moment (in UTC) strictly after ``moment`` (aware) at which the zone's clocks
        show this time. On a day whose clocks jump over it (put forward), the moment they would
        have shown it without the jump (03:30 on a day that skips from 03:00 to 04:00 comes at
        04:30 by the clock); on a day whose clocks show it twice (put back), the first time."""
        if moment.tzinfo is None:
            raise ValueError("moment must carry an offset")
        tz = zoneinfo.ZoneInfo(self.zone)
        day = moment.astimezone(tz).date() - _DAY
        while True:
            # fold=0: in a gap the offset before the jump, in an overlap the first of the two.
            candidate = dt.datetime.combine(day, self.at, tzinfo=tz).astimezone(dt.UTC)
            if candidate > moment:
                return candidate
            day += _DAY
