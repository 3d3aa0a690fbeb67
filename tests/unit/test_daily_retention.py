"""The service's retention schedule without a database: ``ATTUNE_RETENTION_AT`` read and
refused, the next moment a time of day comes (in UTC and across a time zone's changes of clock),
and the schedule's loop on a clock the test moves (it never sleeps for real)."""

from __future__ import annotations

import datetime as dt
from typing import Any

import pytest
from pydantic import ValidationError

from app.daily import DailyTime
from app.services.retention_runs import MAX_SLEEP_S, DailyRetention
from app.settings import Settings

UTC = dt.UTC


def at(text: str) -> dt.datetime:
    """An aware moment from ISO text (with its offset)."""
    return dt.datetime.fromisoformat(text)


def _settings(**values: Any) -> Settings:
    return Settings(_env_file=None, **values)  # type: ignore[call-arg]


class TestSetting:
    @pytest.mark.parametrize(
        ("text", "hour", "minute", "zone"),
        [
            ("03:30", 3, 30, "UTC"),
            ("3:05", 3, 5, "UTC"),
            ("00:00", 0, 0, "UTC"),
            ("23:59 UTC", 23, 59, "UTC"),
            ("  03:30   Europe/London ", 3, 30, "Europe/London"),
        ],
    )
    def test_a_time_and_a_zone(self, text: str, hour: int, minute: int, zone: str) -> None:
        daily = _settings(retention_at=text).retention_at
        assert daily == DailyTime(dt.time(hour, minute), zone)
        assert str(daily) == f"{hour:02d}:{minute:02d} {zone}"

    @pytest.mark.parametrize("text", ["", "   "])
    def test_empty_is_off(self, text: str) -> None:
        assert _settings(retention_at=text).retention_at is None

    def test_off_by_default_and_read_from_the_environment(
        self, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        monkeypatch.delenv("ATTUNE_RETENTION_AT", raising=False)
        assert _settings().retention_at is None
        monkeypatch.setenv("ATTUNE_RETENTION_AT", "04:15 Asia/Shanghai")
        assert _settings().retention_at == DailyTime(dt.time(4, 15), "Asia/Shanghai")

    @pytest.mark.parametrize(
        ("text", "says"),
        [
            ("24:00", "a time of day as HH:MM (00:00 to 23:59)"),
            ("03:60", "a time of day as HH:MM"),
            ("3.30", "a time of day as HH:MM"),
            ("0330", "a time of day as HH:MM"),
            ("03:30 Europe/London extra", "a time of day as HH:MM"),
            ("03:30 Europe", "'Europe' is not an IANA time zone name"),
            ("03:30 Mars/Olympus", "'Mars/Olympus' is not an IANA time zone name"),
        ],
    )
    def test_a_bad_value_is_refused_in_a_sentence(self, text: str, says: str) -> None:
        with pytest.raises(ValidationError) as refused:
            _settings(retention_at=text)
        assert says in str(refused.value)


class TestNextAfter:
    def test_later_today_or_tomorrow_never_now(self) -> None:
        daily = DailyTime(dt.time(3, 30))
        assert daily.next_after(at("2026-12-03T01:00:00+00:00")) == at("2026-12-03T03:30:00+00:00")
        # At the very moment: the next day's (a run that just ended does not run again).
        assert daily.next_after(at("2026-12-03T03:30:00+00:00")) == at("2026-12-04T03:30:00+00:00")
        assert daily.next_after(at("2026-12-03T03:30:01+00:00")) == at("2026-12-04T03:30:00+00:00")
        # A moment given in another offset is the same moment.
        assert daily.next_after(at("2026-12-03T09:00:00+08:00")) == at("2026-12-03T03:30:00+00:00")
        assert daily.next_after(at("2026-12-03T12:00:00+08:00")) == at("2026-12-04T03:30:00+00:00")
        assert daily.next_after(at("2026-12-31T23:59:00+00:00")) == at("2027-01-01T03:30:00+00:00")

    def test_on_the_clocks_of_a_zone(self) -> None:
        london = DailyTime(dt.time(3, 30), "Europe/London")
        # Winter (GMT, UTC+0), then summer (BST, UTC+1): the same wall-clock time.
        assert london.next_after(at("2027-01-10T12:00:00+00:00")) == at("2027-01-11T03:30:00+00:00")
        assert london.next_after(at("2027-06-10T12:00:00+00:00")) == at("2027-06-11T02:30:00+00:00")
        # Across the night the clocks go forward (2027-03-28, 01:00 GMT -> 02:00 BST) and back
        # (2027-10-31, 02:00 BST -> 01:00 GMT): 03:30 is still 03:30 on the clock.
        assert london.next_after(at("2027-03-27T12:00:00+00:00")) == at("2027-03-28T02:30:00+00:00")
        assert london.next_after(at("2027-10-30T12:00:00+00:00")) == at("2027-10-31T03:30:00+00:00")
        shanghai = DailyTime(dt.time(3, 30), "Asia/Shanghai")
        assert shanghai.next_after(at("2026-12-03T12:00:00+00:00")) == at(
            "2026-12-03T19:30:00+00:00"
        )

    def test_a_time_the_clocks_skip_or_show_twice(self) -> None:
        # 01:30 does not exist in London on 2027-03-28: it comes when the clock would have
        # shown it, 01:30 GMT (02:30 BST by the new clock).
        skipped = DailyTime(dt.time(1, 30), "Europe/London")
        assert skipped.next_after(at("2027-03-27T12:00:00+00:00")) == at(
            "2027-03-28T01:30:00+00:00"
        )
        assert skipped.next_after(at("2027-03-28T01:30:00+00:00")) == at(
            "2027-03-29T00:30:00+00:00"
        )
        # 01:30 comes twice on 2027-10-31 (BST, then GMT): the first time only.
        twice = DailyTime(dt.time(1, 30), "Europe/London")
        first = at("2027-10-31T00:30:00+00:00")
        assert twice.next_after(at("2027-10-30T12:00:00+00:00")) == first
        assert twice.next_after(first) == at("2027-11-01T01:30:00+00:00")

    def test_a_moment_without_an_offset_is_refused(self) -> None:
        with pytest.raises(ValueError, match="offset"):
            DailyTime(dt.time(3, 30)).next_after(dt.datetime(2026, 12, 3))


class Clock:
    """The schedule's clock, moved by its waits and by what the runs take."""

    def __init__(self, now: dt.datetime) -> None:
        self.now = now
        self.waits: list[float] = []

    def __call__(self) -> dt.datetime:
        return self.now

    def wait(self, seconds: float) -> bool:
        assert seconds > 0
        self.waits.append(seconds)
        self.now += dt.timedelta(seconds=seconds)
        return False


def _schedule(
    clock: Clock,
    runs: list[dt.datetime],
    *,
    takes: dt.timedelta = dt.timedelta(minutes=3),
    stop_after: int = 3,
    stopping: bool = False,
) -> DailyRetention:
    schedule: DailyRetention

    def run(due: dt.datetime) -> None:
        assert clock.now == due, "a run starts at its time, not before, not later"
        runs.append(due)
        clock.now += takes
        if len(runs) == stop_after:
            schedule.stop()

    schedule = DailyRetention(
        None,  # type: ignore[arg-type]  # the runs are the test's
        None,  # type: ignore[arg-type]
        DailyTime(dt.time(3, 30)),
        stopping=lambda: stopping,
        clock=clock,
        wait=clock.wait,
        run=run,
    )
    return schedule


class TestLoop:
    def test_it_runs_once_a_day_at_the_set_time(self) -> None:
        clock = Clock(at("2026-12-02T22:00:00+00:00"))
        runs: list[dt.datetime] = []
        _schedule(clock, runs).loop()
        assert runs == [
            at("2026-12-03T03:30:00+00:00"),
            at("2026-12-04T03:30:00+00:00"),
            at("2026-12-05T03:30:00+00:00"),
        ]
        # It looked at the clock at least once a minute while it waited, and only waited.
        assert max(clock.waits) == MAX_SLEEP_S
        assert sum(clock.waits) == pytest.approx(
            (at("2026-12-05T03:30:00+00:00") - at("2026-12-02T22:00:00+00:00")).total_seconds()
            - 2 * 180
        )

    def test_a_run_that_outlasts_a_day_skips_the_time_it_missed(self) -> None:
        clock = Clock(at("2026-12-03T03:29:30+00:00"))
        runs: list[dt.datetime] = []
        _schedule(clock, runs, takes=dt.timedelta(hours=25), stop_after=2).loop()
        # The run of the 3rd ended at 04:29 on the 4th: the next is the 5th's, not the 4th's.
        assert runs == [at("2026-12-03T03:30:00+00:00"), at("2026-12-05T03:30:00+00:00")]

    def test_a_service_started_after_the_time_waits_for_the_next_day(self) -> None:
        clock = Clock(at("2026-12-03T03:31:00+00:00"))
        runs: list[dt.datetime] = []
        _schedule(clock, runs, stop_after=1).loop()
        assert runs == [at("2026-12-04T03:30:00+00:00")]

    def test_a_draining_worker_starts_no_run(self) -> None:
        clock = Clock(at("2026-12-03T03:00:00+00:00"))
        runs: list[dt.datetime] = []
        schedule = _schedule(clock, runs, stopping=True)
        schedule.loop()  # it returns once the time comes, without running
        assert runs == []
        assert clock.now == at("2026-12-03T03:30:00+00:00")
        assert schedule.due == at("2026-12-03T03:30:00+00:00")

    def test_a_stopped_schedule_returns_at_once(self) -> None:
        clock = Clock(at("2026-12-03T03:00:00+00:00"))
        runs: list[dt.datetime] = []
        schedule = _schedule(clock, runs)
        assert schedule.stop() is True  # never started: nothing to wait for
        schedule.loop()
        assert runs == []
        assert clock.waits == []
