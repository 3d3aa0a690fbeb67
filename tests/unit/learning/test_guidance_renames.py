"""A mission change carries the staff's corrections by name: renamed names follow, removed
ones leave the rule idle (no effect, no error)."""

from __future__ import annotations

import numpy as np

from app.learning import Mission, Renames, make_learner, office_mission, remap_learner
from app.learning.guidance import Rule, RuleKind


def _renamed_mission() -> Mission:
    doc = office_mission().to_dict()
    doc["situations"] = ["stretch_break" if s == "stretching" else s for s in doc["situations"]]
    doc["services"] = [
        {"name": s["name"], "details": ["green_tea" if d == "tea" else d for d in s["details"]]}
        for s in doc["services"]
    ]
    return Mission.from_dict(doc)


def test_renamed_names_follow() -> None:
    learner = make_learner("hri", None, office_mission())
    learner.correct(Rule("r", RuleKind.PREFERS, "morning", "stretching", "ProvideDrink", "tea"))
    new = _renamed_mission()
    moved = remap_learner(
        learner,
        new,
        Renames(situations={"stretching": "stretch_break"}, details={"tea": "green_tea"}),
    )
    [rule] = moved.guidance.rules
    assert (rule.situation, rule.detail) == ("stretch_break", "green_tea")
    view = moved.explain(new.context_index("morning", "stretch_break"), 1)
    assert view.probabilities[moved.space.INITIATE] >= 0.99
    # the learner it came from keeps its own names
    assert learner.guidance.rules[0].situation == "stretching"


def test_a_removed_name_leaves_the_rule_idle() -> None:
    learner = make_learner("hri", None, office_mission())
    fresh = make_learner("hri", None, _renamed_mission())
    learner.correct(Rule("r", RuleKind.QUIET, "morning", "stretching"))
    moved = remap_learner(learner, _renamed_mission())  # no renames: "stretching" is gone
    assert [r.id for r in moved.guidance.rules] == ["r"]
    for c in range(moved.space.n_contexts):
        assert np.array_equal(moved.explain(c, 1).probabilities, fresh.explain(c, 1).probabilities)
