"""The map of the paper's claims (app/learning/claims_map.py): the default setting is exactly what
every command runs, settings are labelled as readings, the grid and its worlds, the missions with
coarser and finer time slots, R-MAX's optimism, and the map's shares and best settings."""

from __future__ import annotations

import math
from datetime import time

import numpy as np
import pytest

from app.learning import HriParams, RmaxParams, make_learner, office_mission
from app.learning.claims import check_claims
from app.learning.claims_map import (
    AXES,
    ClaimMap,
    Grid,
    Setting,
    World,
    build_map,
    method_key,
    setting_methods,
    with_time_slots,
)
from app.learning.evaluation import E1E2, E3, PAPER_METHODS, run
from app.learning.simulation import UserProfile


class TestDefault:
    def test_is_what_every_command_runs(self) -> None:
        default = Setting.default()
        profile = UserProfile(())
        assert default.world().user_params() == {
            "p_acc": profile.p_acc,
            "p_self": profile.p_self,
            "eps_fb": profile.eps_fb,
        }
        assert default["time_slots"] == len(office_mission().time_slots)
        assert default.world().mission(office_mission()) is office_mission()
        assert (default["m"], default["optimism"]) == (RmaxParams().m, RmaxParams().optimism)
        assert (default["exclusion"], default["pref_scale"]) == (
            HriParams().exclusion,
            HriParams().pref_scale,
        )

    def test_its_methods_are_the_papers(self) -> None:
        mission = office_mission()
        paper = {m.label: m for m in PAPER_METHODS}
        for method in setting_methods(Setting.default()):
            same = paper[method.label]
            assert method.algorithm == same.algorithm
            assert method.key == same.key  # the same random draws
            ours = make_learner(method.algorithm, method.params, mission)
            theirs = make_learner(same.algorithm, same.params, mission)
            assert ours.params == theirs.params

    def test_labels_say_reading_not_paper(self) -> None:
        assert Setting.default().label() == "default"
        assert Setting.default().is_default
        for setting in Grid.full().settings():
            if not setting.is_default:
                assert setting.label().startswith("reading: ")
            assert "paper" not in setting.label()
        assert Setting.of(m=1, exclusion="none").label() == "reading: m=1, exclusion=none"


class TestSetting:
    def test_refuses_values_outside_the_ranges(self) -> None:
        with pytest.raises(ValueError, match="m=3"):
            Setting.of(m=3)
        with pytest.raises(ValueError, match="gamma is not an axis"):
            Setting.of(gamma=0.5)
        with pytest.raises(ValueError, match="values"):
            Setting((1, 2))

    def test_changes_name_only_the_axes_that_differ(self) -> None:
        setting = Setting.of(noise=0.0, pref_scale="raw")
        assert setting.changes() == {"noise": 0.0, "pref_scale": "raw"}
        assert setting.world() == World(4, 0.5, 0.0)
        assert setting.world().user_params() == {"p_acc": 1.0, "p_self": 0.5, "eps_fb": 0.0}


class TestGrid:
    def test_full_grid_is_every_combination(self) -> None:
        grid = Grid.full()
        settings = grid.settings()
        assert len(settings) == math.prod(len(a.values) for a in AXES)
        assert len(set(settings)) == len(settings)
        assert Setting.default() in settings
        world_axes = [a for a in AXES if a.scope == "world"]
        assert len(grid.worlds()) == math.prod(len(a.values) for a in world_axes)

    def test_each_method_variant_once(self) -> None:
        grid = Grid.full()
        methods = grid.methods()
        keys = [method_key(m) for m in methods]
        assert len(set(keys)) == len(keys)
        size = {
            scope: math.prod(len(a.values) for a in AXES if a.scope == scope)
            for scope in ("rmax", "hri")
        }
        # R-MAX variants, one Q-learning, and the HRI variants at both temperatures
        assert len(methods) == size["rmax"] + 1 + 2 * size["hri"]
        assert {m.label for m in methods} == {m.label for m in PAPER_METHODS[:4]}

    def test_quick_grid_is_within_the_full_one_and_holds_the_default(self) -> None:
        quick = Grid.quick().settings()
        assert set(quick) <= set(Grid.full().settings())
        assert Setting.default() in quick
        assert len(quick) < len(Grid.full().settings())

    def test_refuses_a_value_outside_its_axis(self) -> None:
        values = {a.key: a.values for a in AXES}
        with pytest.raises(ValueError, match="within"):
            Grid({**values, "m": (1, 7)})
        with pytest.raises(ValueError, match="exactly the axes"):
            Grid({k: v for k, v in values.items() if k != "m"})


class TestTimeSlots:
    @pytest.mark.parametrize("n", [2, 8])
    def test_every_minute_falls_in_a_slot_of_the_same_part_of_the_day(self, n: int) -> None:
        office = office_mission()
        other = with_time_slots(office, n)
        assert len(other.time_slots) == n
        assert other.n_contexts == n * len(office.situations)
        assert (other.situations, other.services, other.rewards, other.gamma) == (
            office.situations,
            office.services,
            office.rewards,
            office.gamma,
        )
        for minute in range(0, 24 * 60, 15):
            t = time(minute // 60, minute % 60)
            mine = next(s.name for s in office.time_slots if s.contains(t))
            theirs = [s.name for s in other.time_slots if s.contains(t)]
            assert len(theirs) == 1
            # merged slots name both of theirs; split ones name their slot and a half
            assert mine in theirs[0].replace(".", "-").split("-")

    def test_refuses_other_counts(self) -> None:
        with pytest.raises(ValueError, match="neither"):
            with_time_slots(office_mission(), 3)


class TestRmaxOptimism:
    @pytest.mark.parametrize("optimism", [1.0, 0.1])
    def test_unknown_pairs_are_worth_optimism_times_vmax(self, optimism: float) -> None:
        mission = office_mission()
        learner = make_learner("rmax", {"optimism": optimism}, mission)
        q = learner.explain(0, 1).q
        assert np.allclose(q, optimism * mission.v_max)

    @pytest.mark.parametrize("bad", [0.0, -0.5, 1.5, "high"])
    def test_refuses_values_outside_0_1(self, bad: object) -> None:
        with pytest.raises(ValueError, match="optimism"):
            RmaxParams.from_dict({"optimism": bad})


def _map(verdicts: dict[Setting, list[bool]]) -> ClaimMap:
    n = len(next(iter(verdicts.values())))
    return ClaimMap([(f"c{i}", f"claim {i}") for i in range(n)], verdicts)


class TestClaimMap:
    def test_shares_best_marginals_and_histogram(self) -> None:
        default, one, two = Setting.default(), Setting.of(m=1), Setting.of(m=1, noise=0.0)
        claim_map = _map(
            {default: [True, False, False], two: [True, True, False], one: [True, True, False]}
        )
        assert [claim_map.share(i) for i in range(3)] == [1.0, 2 / 3, 0.0]
        assert claim_map.best() == [one, two]  # tied: fewest changes first
        assert claim_map.held(default) == 1
        assert claim_map.histogram() == [0, 1, 2, 0]
        assert claim_map.marginal("m", 1) == 4 / 6
        assert claim_map.marginal("m", 2, claim=1) == 0.0
        assert math.isnan(claim_map.marginal("m", 4))

    def test_decided_like_the_paper_command_under_the_default(self) -> None:
        """A tiny sweep (one world, two R-MAX thresholds): the default setting's verdicts are
        those of check_claims on the paper's own methods with the same seeds."""
        mission = office_mission()
        values = {a.key: (a.default,) for a in AXES}
        grid = Grid({**values, "m": (1, 2)})
        world = Setting.default().world()
        runs = {}
        for method in grid.methods():
            runs[(world, method_key(method))] = [
                run(method, protocol, 0, mission, n_users=1, user_params=world.user_params())
                for protocol in (E1E2, E3)
            ]
        claim_map = build_map(grid.settings(), runs)
        assert len(claim_map.claims) == 12  # the paper's; DTS is not run
        paper = [run(m, p, 0, mission, n_users=1) for m in PAPER_METHODS[:4] for p in (E1E2, E3)]
        assert claim_map.verdicts[Setting.default()] == [c.reproduced for c in check_claims(paper)]
        # Q-learning's runs are shared, and its rebound does not involve R-MAX
        rebound = [key for key, _ in claim_map.claims].index("E1-Q-rebound")
        assert len({v[rebound] for v in claim_map.verdicts.values()}) == 1

    def test_a_missing_run_is_an_error(self) -> None:
        with pytest.raises(KeyError, match="no runs of R-MAX"):
            build_map([Setting.default()], {})
