"""The console's pure pieces, without a browser: the reward curve's thinning, the heatmap's
reading of a policy, the profile's words and local times, where signing in may send the
browser, the CSRF token."""

from __future__ import annotations

import datetime as dt
from typing import Any

import pytest

from app.console.auth import csrf_token, safe_next
from app.console.views import (
    correction_status,
    correction_words,
    curve,
    evidence_why,
    expectation,
    fmt_aware,
    fmt_count,
    fmt_local,
    fmt_measure,
    fmt_offset,
    heat_class,
    learner_summary,
    name_words,
    robot_words,
    wanted_words,
)
from app.learning.offpolicy import Steps, estimate
from app.schemas.models import ContextModel
from app.schemas.profile import CorrectionOut, RobotWill, Wanted


class TestCurve:
    def test_short_histories_are_drawn_whole(self) -> None:
        assert curve([0.0, 1.0, -1.0]) == ([0, 1, 2], [0.0, 1.0, -1.0])

    def test_long_histories_keep_ends_and_extremes_within_the_budget(self) -> None:
        values = [float((i % 97) - (i % 13)) for i in range(50_001)]
        values[31_337] = 1e6  # one spike must survive thinning
        xs, ys = curve(values, max_points=1000)
        assert len(xs) <= 1002
        assert xs[0] == 0
        assert xs[-1] == 50_000
        assert xs == sorted(set(xs))
        assert ys == [values[i] for i in xs]
        assert 31_337 in xs
        assert min(ys) == min(values)


def _context(
    engaged: list[tuple[str, str | None, float]],
    type_known: dict[str, list[tuple[str, str | None, float]]],
    visited: bool = True,
) -> ContextModel:
    def actions(
        rows: list[tuple[str, str | None, float]], service: str | None = None
    ) -> list[dict[str, Any]]:
        out = []
        for kind, name, p in rows:
            action: dict[str, Any] = {"kind": kind}
            if kind == "infer_type":
                action["service"] = name
            elif kind == "infer_detail":
                action.update(service=service, detail=name)
            elif kind == "query_detail":
                action["service"] = service
            out.append(
                {
                    "action": action,
                    "q": 0.0,
                    "visits": int(visited),
                    "kept_visits": None,
                    "since_last": 1,
                    "measure": None,
                    "p": p,
                }
            )
        return out

    states = [
        {"state": "OBSERVE", "actions": actions([("initiate", None, 0.7), ("pass", None, 0.3)])},
        {"state": "ENGAGED", "actions": actions(engaged)},
        *(
            {"state": "TYPE_KNOWN", "service": k, "actions": actions(rows, k)}
            for k, rows in type_known.items()
        ),
    ]
    return ContextModel.model_validate(
        {"time_slot": "afternoon", "situation": "stretching", "states": states}
    )


class TestExpectation:
    def test_the_likeliest_guess_and_the_chance_of_asking(self) -> None:
        ctx = _context(
            [("query_type", None, 0.2), ("infer_type", "Drink", 0.6), ("infer_type", "Info", 0.2)],
            {
                "Drink": [
                    ("query_detail", None, 0.1),
                    ("infer_detail", "tea", 0.8),
                    ("infer_detail", "coffee", 0.1),
                ],
                "Info": [("query_detail", None, 0.5), ("infer_detail", "news", 0.5)],
            },
        )
        e = expectation(ctx)
        assert e is not None
        assert (e.service, e.detail) == ("Drink", "tea")
        assert e.p_guess == pytest.approx(0.6 * 0.8)
        assert e.p_ask == pytest.approx(0.2 + 0.6 * 0.1 + 0.2 * 0.5)

    def test_a_tie_is_no_preference_and_never_engaged_is_nothing(self) -> None:
        rows: dict[str, list[tuple[str, str | None, float]]] = {
            "Drink": [("infer_detail", "tea", 0.5), ("infer_detail", "coffee", 0.5)]
        }
        tie = expectation(_context([("query_type", None, 0.5), ("infer_type", "Drink", 0.5)], rows))
        assert tie is not None
        assert (tie.service, tie.p_guess, tie.p_ask) == (None, None, 0.5)
        assert expectation(_context([("infer_type", "Drink", 1.0)], rows, visited=False)) is None


def test_number_formats() -> None:
    assert fmt_count(3) == "3"
    assert fmt_count(2.5) == "2.50"
    assert fmt_count(None) == "—"
    assert fmt_measure(123456.0) == "1.23e+05"
    assert heat_class(0.04) == "heat-0"
    assert heat_class(0.96) == "heat-10"
    assert heat_class(None) == "heat-none"


@pytest.mark.parametrize(
    ("asked", "goes"),
    [
        ("/admin/users/lin", "/admin/users/lin"),
        ("/admin/users?q=a&page=2", "/admin/users?q=a&page=2"),
        (None, "/admin/users"),
        ("https://evil.example/admin/", "/admin/users"),
        ("//evil.example/admin/x", "/admin/users"),
        ("/admin\\..\\x", "/admin/users"),
        ("/v1/users", "/admin/users"),
        ("/admin/users/\r\nSet-Cookie:x", "/admin/users"),
    ],
)
def test_signing_in_only_returns_to_console_pages(asked: str | None, goes: str) -> None:
    assert safe_next(asked) == goes


def test_the_csrf_token_is_derived_from_the_key_and_hides_it() -> None:
    token = csrf_token("att_secret")
    assert token == csrf_token("att_secret")
    assert token != csrf_token("att_other")
    assert "att_secret" not in token
    assert len(token) == 64


def test_learner_summary_names_the_variant() -> None:
    assert learner_summary("hri", {"tau": 0.01}) == "hri τ=0.01"
    assert learner_summary("rmax", {"m": 2}) == "rmax m=2"
    assert learner_summary("qlearning", {"exploration": "epsilon"}) == "qlearning ε-greedy"
    assert learner_summary("qlearning", {"exploration": "boltzmann"}) == "qlearning Boltzmann"
    assert learner_summary("someday", {}) == "someday"


class TestProfileWords:
    def test_local_times_say_their_offset_or_utc(self) -> None:
        at = dt.datetime(2026, 11, 30, 23, 30, tzinfo=dt.UTC)
        assert fmt_local(at, 480) == "2026-12-01 07:30 (UTC+8)"
        assert fmt_local(at, -330) == "2026-11-30 18:00 (UTC−5:30)"
        assert fmt_local(at, None) == "2026-11-30 23:30 UTC"
        assert fmt_local(at, 0) == "2026-11-30 23:30 (UTC)"
        assert fmt_local(None, 60) == "—"
        assert fmt_offset(60) == "UTC+1"
        local = dt.datetime(2026, 11, 3, 9, 12, tzinfo=dt.timezone(dt.timedelta(hours=8)))
        assert fmt_aware(local) == "2026-11-03 09:12 (UTC+8)"

    def test_names_and_wishes_in_words(self) -> None:
        assert name_words("ProvideDrink") == "Provide drink"
        assert name_words("today_agenda") == "today agenda"
        assert name_words("busy") == "busy"
        assert wanted_words(Wanted(service="ProvideDrink", detail="tea")) == "Provide drink (tea)"
        assert wanted_words(Wanted(service="BriefInformation")) == "Brief information"
        assert wanted_words(None) == "Nothing in particular"

    @pytest.mark.parametrize(
        ("action", "service", "asks", "words"),
        [
            ("offer", "ProvideDrink", False, "Offers it without asking"),
            ("offer", "ProvideDrink", True, "Offers help and asks what first"),
            ("offer", None, True, "Offers help and asks what first"),
            ("wait_to_be_asked", None, False, "Waits to be asked"),
            ("stay_away", None, False, "Stays away"),
        ],
    )
    def test_what_the_robot_will_do(
        self, action: Any, service: str | None, asks: bool, words: str
    ) -> None:
        will = RobotWill(
            action=action, service=service, detail=None, asks_first=asks, probability=0.5
        )
        assert robot_words(will) == words

    def test_corrections_in_words(self) -> None:
        def made(
            kind: Any,
            status: Any = "in_force",
            service: str | None = None,
            detail: str | None = None,
        ) -> CorrectionOut:
            return CorrectionOut(
                correction_id="c1",
                kind=kind,
                time_slot="morning",
                situation="arriving",
                service=service,
                detail=detail,
                note=None,
                author="key_1",
                created_at=dt.datetime(2026, 11, 30, tzinfo=dt.UTC),
                status=status,
                model_version=2,
            )

        assert (
            correction_words(made("prefers", service="ProvideDrink", detail="coffee"))
            == "Prefers Provide drink (coffee)"
        )
        assert (
            correction_words(made("avoid", service="BriefInformation"))
            == "Do not offer Brief information"
        )
        assert correction_words(made("quiet")) == "Quiet: the robot does not offer help"
        assert correction_status(made("quiet")) == "In force"
        assert (
            correction_status(made("prefers", "overridden"), "Mrs. Lin")
            == "Overridden by Mrs. Lin's own answers"
        )


# -- labels, the fleet's time zone, steps in words, refusals ---------------------------------
def _labelled() -> Any:
    from app.learning import Mission, office_mission

    return Mission.from_dict(
        {
            **office_mission().to_dict(),
            "labels": {"ProvideDrink": "a drink", "tea": "a cup of tea"},
            "time_zone": "Asia/Tokyo",
        }
    )


def test_labels_read_as_the_mission_says_and_default_to_a_readable_id() -> None:
    from app.console.views import label, wanted_label

    m = _labelled()
    assert label(m, "ProvideDrink") == "a drink"
    assert label(m, "BriefInformation") == "Brief information"
    assert wanted_label(m, "ProvideDrink", "tea") == "a drink (a cup of tea)"
    assert wanted_label(m, None, None) == "Nothing in particular"


def test_times_are_in_the_fleets_time_zone() -> None:
    from app.console.views import fmt_zone, zone_note

    at = dt.datetime(2026, 11, 3, 1, 12, tzinfo=dt.UTC)
    assert fmt_zone(at, "Asia/Tokyo") == "2026-11-03 10:12"
    assert fmt_zone(at, "UTC") == "2026-11-03 01:12"
    assert fmt_zone(at.replace(tzinfo=None), "Europe/London") == "2026-11-03 01:12"  # naive: UTC
    summer = dt.datetime(2026, 7, 3, 1, 12, tzinfo=dt.UTC)
    assert fmt_zone(summer, "Europe/London") == "2026-07-03 02:12"  # the zone's own rules
    assert fmt_zone(None, "UTC") == "—"
    assert zone_note("Asia/Tokyo") == "Times are in the fleet's time zone, Asia/Tokyo."


def test_a_decision_in_words() -> None:
    from app.console.views import person_step_words, robot_step_words
    from app.schemas.common import ActionOut, ProbabilityOut

    m = _labelled()

    class Decision:
        def __init__(self, action: ActionOut, chain: list[ProbabilityOut]) -> None:
            self.action, self.chain = action, chain

    guess = ProbabilityOut(action=ActionOut(kind="infer_type", service="ProvideDrink"), p=0.8)
    ask = ActionOut(kind="query_detail", service="ProvideDrink")
    assert robot_step_words(m, Decision(ask, [guess])) == (
        "Guessed a drink was wanted, asked which one"
    )
    assert robot_step_words(m, Decision(ActionOut(kind="initiate"), [])) == "Offered help"
    performed = ActionOut(kind="perform", service="ProvideDrink", detail="tea")
    assert robot_step_words(m, Decision(performed, [])) == "Brought a cup of tea (a drink)"
    assert person_step_words(m, "Mrs. Lin", "answered", "ProvideDrink", "tea") == (
        "Mrs. Lin answered: a cup of tea"
    )
    assert person_step_words(m, "Mrs. Lin", "rejected", None, None) == "Mrs. Lin turned it down"
    assert person_step_words(m, "Mrs. Lin", None, None, None) == "Waiting for Mrs. Lin's answer"


def test_the_cores_reasons_become_the_forms_sentences() -> None:
    from app.console.views import refusal_words
    from app.learning.guidance import Rule, RuleKind

    m = _labelled()

    def said(kind: RuleKind, service: str | None = None, detail: str | None = None) -> str:
        rule = Rule("c1", kind, "morning", "arriving", service, detail)
        return refusal_words(rule.reasons(m), m, "north")

    assert said(RuleKind.PREFERS) == "Choose what the person prefers."
    assert said(RuleKind.AVOID) == "Choose what the robot should not offer."
    assert said(RuleKind.PREFERS, "ProvideDrink") == (
        "Choose the person's choice of a drink: a cup of tea, coffee or water."
    )
    assert said(RuleKind.AVOID, "ProvideDrink", "news") == (
        "“news” is not a choice of a drink: choose a cup of tea, coffee or water."
    )
    assert said(RuleKind.AVOID, "Massage") == (
        "The robots of fleet north do not offer “Massage” any more: choose another service."
    )


def test_the_learner_in_use_is_explained() -> None:
    from app.console.views import learner_words, p_words

    assert "Pref" in p_words("hri")
    assert "Pref" not in p_words("dts-adapt")
    assert "share of the drawn models" in p_words("dts-adapt")
    assert learner_words("dts-adapt") != learner_words("hri")


def test_why_there_is_no_estimate_reads_in_staff_words() -> None:
    # A doubly robust estimate refused because the candidate's model expects far more than any
    # logged encounter earned: the staff's sentence names the learner, not the symbols.
    seen = {"logged": [0.9], "target": [0.9], "reward": [1.0], "q_hat": [40.0], "v_hat": [40.0]}
    result = estimate(Steps.from_episodes([seen] * 40, list(range(40))), "wdr")
    assert not result.enough
    words = evidence_why("R-MAX", result.reason)
    assert words.startswith("R-MAX expects more (or less) of these encounters")
    assert "40.00" not in words
    few = estimate(Steps.from_episodes([seen] * 5, list(range(5))), "wpdis")
    assert evidence_why("DTS", few.reason).startswith("too few of the robots' encounters")
