"""A mission's display fields, labels and time zone: validated, read back, and outside the
fingerprint (a mission that changes only them is the same mission for learning). Pure: numpy
and the stdlib."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from app.learning import Mission, MissionError, office_mission
from app.learning.mission import readable

ROOT = Path(__file__).resolve().parents[3]


def _doc(**extra: Any) -> dict[str, Any]:
    return {**office_mission().to_dict(), **extra}


class TestLabels:
    @pytest.mark.parametrize(
        ("name", "words"),
        [
            ("ProvideDrink", "Provide drink"),
            ("phone_call", "phone call"),
            ("today_agenda", "today agenda"),
            ("personal_care", "personal care"),
            ("TV", "TV"),
            ("lunch", "lunch"),
        ],
    )
    def test_a_name_without_a_label_reads_as_its_readable_form(self, name: str, words: str) -> None:
        assert readable(name) == words

    def test_a_label_is_what_staff_read_and_the_rest_default(self) -> None:
        m = Mission.from_dict(_doc(labels={"tea": "a cup of tea", "ProvideDrink": "a drink"}))
        assert m.label("tea") == "a cup of tea"
        assert m.label("ProvideDrink") == "a drink"
        assert m.label("BriefInformation") == "Brief information"
        assert m.label(None) == ""
        assert Mission.from_dict(m.to_dict()) == m  # read back as written

    def test_labels_and_time_zone_leave_the_fingerprint_as_it_was(self) -> None:
        plain = Mission.from_dict(_doc())
        labelled = Mission.from_dict(
            _doc(labels={"tea": "a cup of tea", "busy": "in a meeting"}, time_zone="Asia/Tokyo")
        )
        assert labelled.fingerprint == plain.fingerprint == office_mission().fingerprint
        assert labelled.shape() == plain.shape()
        assert not labelled.same_display(plain)
        # Whereas a change of a name is another mission.
        renamed = _doc()
        renamed["situations"] = ["arriving", "working", "stretching", "away"]
        renamed["unavailable_situations"] = ["away"]
        assert Mission.from_dict(renamed).fingerprint != plain.fingerprint

    @pytest.mark.parametrize(
        ("labels", "message"),
        [
            ({"cha": "tea"}, "labels.cha: 'cha' is not a time slot, situation, service or detail"),
            ({"tea": ""}, "labels.tea: a label is text of 1 to 64 characters"),
            ({"tea": 5}, "labels.tea: a label is text of 1 to 64 characters"),
            ({"tea": "x" * 65}, "labels.tea: a label is text of 1 to 64 characters"),
            ({"tea": "a\ncup"}, "labels.tea: a label must not hold control characters"),
            (["tea"], "labels: expected an object, got list"),
        ],
    )
    def test_a_bad_label_is_refused_naming_it(self, labels: object, message: str) -> None:
        with pytest.raises(MissionError, match=message.replace("(", r"\(").replace(")", r"\)")):
            Mission.from_dict(_doc(labels=labels))

    def test_the_care_home_example_has_labels_for_its_custom_names(self) -> None:
        doc = json.loads((ROOT / "docs/examples/care-home-mission.json").read_text())
        m = Mission.from_dict(doc)
        assert m.label("phone_call") == "a phone call"
        assert m.label("personal_care") == "in personal care"
        assert m.time_zone == doc["time_zone"]
        without = {k: v for k, v in doc.items() if k not in ("labels", "time_zone")}
        assert Mission.from_dict(without).fingerprint == m.fingerprint


class TestTimeZone:
    def test_utc_by_default_and_an_iana_name_kept(self) -> None:
        assert Mission.from_dict(_doc()).time_zone == "UTC"
        assert "time_zone" not in Mission.from_dict(_doc()).to_dict()
        assert Mission.from_dict(_doc(time_zone="Europe/London")).time_zone == "Europe/London"

    @pytest.mark.parametrize(
        "zone",
        # "Europe" is a folder of the time zone database, not a zone (ZoneInfo raised an
        # OSError on it, which was no mission error).
        ["Mars/Olympus", "", "+08:00", 8, "../etc/passwd", "Europe", "America"],
    )
    def test_anything_else_is_refused(self, zone: object) -> None:
        with pytest.raises(MissionError, match="time_zone: .* is not an IANA time zone name"):
            Mission.from_dict(_doc(time_zone=zone))


def test_the_order_of_the_labels_does_not_matter() -> None:
    one = Mission.from_dict(_doc(labels={"tea": "a cup of tea", "busy": "in a meeting"}))
    other = Mission.from_dict(_doc(labels={"busy": "in a meeting", "tea": "a cup of tea"}))
    assert one == other
    assert Mission.from_dict(json.loads(json.dumps(one.to_dict(), sort_keys=True))) == one
