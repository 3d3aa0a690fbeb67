"""The conformance suite every learner must pass: :func:`check_learner`, the phased driver.

One call drives a learner (built by name through ``app.learning.learners``) in five phases and
raises ``AssertionError`` with a sentence naming the learner, the phase and what went wrong:

1. **Parameters.** Every field of the learner's parameter dataclass refuses a value of the wrong
   type, NaN and infinity (numbers), and values far outside any sensible range (every numeric
   parameter must be bounded), each with a ``ValueError`` whose message names the parameter. An
   unknown parameter is refused too.
2. **Fresh learner.** Version 0, the requested parameters, a finite ``explain`` everywhere, and an
   export that imports back.
3. **Simulated user, twice in lockstep.** Two learners with the same seeds face one simulated user
   (``app.learning.simulation``: a random profile whose needs drift half way). Every decision is
   checked (valid actions, silent chain steps, a visible final action, distributions that sum to
   one), both learners must decide identically and export identical states, and one of them is
   repeatedly replaced by its export -> JSON -> import clone, mid-episode included.
4. **Adversarial transitions** on one learner: invalid reports (refused with ``ValueError``, the
   learner unchanged), thousands of identical root rejections, thousands of identical accepted
   services, a long run of the same wrong service, then random structurally valid reports (any
   action, any successor, any signal, split or batched arbitrarily, episodes interleaved or left
   open) with episode indices jumping to 10**9 and 10**12. ``update`` must add exactly one to
   ``version`` every time.
5. **Checkpoints** after each block and at the end: decisions from every state of several
   contexts, ``explain`` in every context at current, huge and out-of-order episode indices, all
   finite; ``select_action`` and ``explain`` leave the export unchanged; exported arrays are
   finite; the export -> JSON -> import round trip gives the same version, an identical re-export
   and the same next decisions under the same generator.

Each call the driver makes goes through the per-call checks of :mod:`.invariants`. The suite uses
numpy and the standard library only, so it runs wherever the learning core does.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..config import PARAMS
from ..learners import make_learner
from ..mission import Mission
from ..protocols import Learner
from ..simulation import STEP_COLUMNS, drift, event_stream, random_profile, respond
from ..space import Action, ActionKind, NegotiationSpace
from ..types import Observation, Polarity, Transition
from .invariants import CallChecks, canonical

__all__ = ["check_learner"]

_SIM_EPISODES = 60  # simulated-user episodes of phase 3 (about 150 update calls)
_HUGE = (10**9, 10**12)  # the episode indices of the staleness jumps


def check_learner(
    algorithm: str,
    mission: Mission,
    params: Mapping[str, Any] | None = None,
    *,
    seed: int = 0,
    updates: int = 10_000,
) -> None:
    """Run the conformance suite on ``algorithm`` with ``params`` over ``mission``.

    ``updates`` is the number of ``update`` calls the stressed learner receives in all (the
    simulated phase included; at least that phase always runs). ``seed`` fixes every draw, so a
    failure reproduces exactly. Raises ``AssertionError`` naming what does not conform, and
    ``ValueError`` when ``algorithm`` or ``params`` themselves are invalid.
    """
    if isinstance(updates, bool) or not isinstance(updates, int) or updates < 0:
        raise ValueError(f"updates must be a whole number of 0 or more, got {updates!r}.")
    _Suite(algorithm, mission, params, seed).run(updates)


class _Suite:
    """Drives learners of one algorithm through the five phases; :attr:`check` checks each call."""

    def __init__(
        self, algorithm: str, mission: Mission, params: Mapping[str, Any] | None, seed: int
    ) -> None:
        self.algorithm = algorithm
        self.mission = mission
        self.params = dict(params or {})
        first = make_learner(algorithm, self.params, mission)  # ValueError on bad input
        self.space: NegotiationSpace = first.space
        label = algorithm + (f" {self.params}" if self.params else "")
        self.check = CallChecks(label, mission, self.space, seed)
        r = mission.rewards
        self.vocabulary = (
            0.0,
            r.positive,
            r.negative,
            r.query,
            r.query + r.negative,
            r.max_step,
        )

    def make(self) -> Learner:
        return make_learner(self.algorithm, self.params, self.mission)

    # -- the phases --------------------------------------------------------------------------------
    def run(self, updates: int) -> None:
        self.check.phase = "parameter validation"
        self.check_params()

        self.check.phase = "fresh learner"
        a, b = self.make(), self.make()
        self.check_fresh(a)

        self.check.phase = "simulated user"
        a, b, episode = self.simulated(a, b)
        a = self.checkpoint(a, episode + 1, contexts=range(min(4, self.space.n_contexts)))

        self.check.phase = "adversarial transitions"
        self.check_refusals(a, episode + 1)
        budget = max(0, updates - self.check.calls)
        plan = [
            ("identical root rejections", 0.2, self.root_rejections),
            ("identical accepted services", 0.4, self.accepted_services),
            ("identical wrong services", 0.1, self.wrong_services),
        ]
        for name, share, block in plan:
            self.check.phase = name
            episode = block(a, episode, int(budget * share))
            a = self.checkpoint(a, episode + 1, contexts=self.hot_contexts())
        self.check.phase = "random adversarial transitions with staleness jumps"
        episode = self.random_block(a, episode, updates)
        self.check.phase = "final checks"
        self.final(a, episode)

    # -- 1. parameters -----------------------------------------------------------------------------
    def check_params(self) -> None:
        cls = PARAMS[self.algorithm]
        defaults = cls()
        for f in dataclasses.fields(cls):
            for bad, why in _bad_values(getattr(defaults, f.name)):
                try:
                    make_learner(self.algorithm, {f.name: bad}, self.mission)
                except ValueError as exc:
                    if f.name not in str(exc):
                        self.check.fail(
                            f"{f.name}={bad!r} ({why}) was refused, but the message does not "
                            f"name the parameter: {exc}"
                        )
                except Exception as exc:  # any other exception is the finding
                    self.check.fail(
                        f"{f.name}={bad!r} ({why}) raised {type(exc).__name__} instead of "
                        f"ValueError: {exc}"
                    )
                else:
                    self.check.fail(f"{f.name}={bad!r} ({why}) was accepted; it must be refused.")
        try:
            make_learner(self.algorithm, {"no_such_parameter": 1}, self.mission)
        except ValueError as exc:
            if "no_such_parameter" not in str(exc):
                self.check.fail(f"an unknown parameter was refused without naming it: {exc}")
        except Exception as exc:  # any other exception is the finding
            self.check.fail(
                f"an unknown parameter raised {type(exc).__name__}, not ValueError: {exc}"
            )
        else:
            self.check.fail("an unknown parameter (no_such_parameter) was accepted.")

    # -- 2. fresh learner --------------------------------------------------------------------------
    def check_fresh(self, learner: Learner) -> None:
        if learner.algorithm != self.algorithm:
            self.check.fail(f"the learner calls itself {learner.algorithm!r}.")
        if learner.version != 0:
            self.check.fail(f"a fresh learner has version {learner.version}, expected 0.")
        want = PARAMS[self.algorithm].from_dict(self.params)
        if learner.params != want:
            self.check.fail(f"the learner holds params {learner.params!r}, expected {want!r}.")
        for c in range(self.space.n_contexts):
            self.check.explain(learner, c, 1)
        self.check.round_trip(learner, self.probes(1, range(min(4, self.space.n_contexts))))

    # -- 3. simulated user, two learners in lockstep -----------------------------------------------
    def simulated(self, a: Learner, b: Learner) -> tuple[Learner, Learner, int]:
        space, mission = self.space, self.mission
        n = _SIM_EPISODES
        before = random_profile(mission, self.check.rng(1))
        after = drift(before, mission, self.check.rng(2))
        change = n // 2
        contexts = event_stream([before, after], [0, change], mission, n, self.check.rng(3))
        uniforms = self.check.rng(4).random((n, STEP_COLUMNS))
        rng_a, rng_b = self.check.rng(5), self.check.rng(5)
        for e in range(n):
            episode, context = e + 1, int(contexts[e])
            profile = before if e < change else after
            state, step = space.OBSERVE, 0
            while state != space.END:
                if 2 * step + 2 > STEP_COLUMNS:
                    self.check.fail(f"episode {episode} did not end after {step} visible actions.")
                obs = Observation(context, state, episode)
                da = self.check.decide(a, obs, rng_a)
                db = self.check.decide(b, obs, rng_b)
                self.check.same_decision(
                    da, db, f"two learners with the same seed, {self.check.at(obs)}"
                )
                batch = da.chain_transitions(episode)
                reaction = respond(
                    space,
                    profile,
                    context,
                    da.state,
                    da.action,
                    uniforms[e, 2 * step : 2 * step + 2],
                )
                batch.append(
                    Transition(
                        episode,
                        context,
                        da.state,
                        da.action,
                        reaction.reward,
                        reaction.next_state,
                        reaction.signal,
                    )
                )
                self.check.update(a, batch)
                self.check.update(b, batch, count=False)
                state, step = reaction.next_state, step + 1
                if e % 12 == 5 and step == 1 and state != space.END:
                    # Mid-episode: the open episode's samples must travel with the export.
                    b = self.check.round_trip(b, self.probes(episode, [context], state=state))
            if e % 10 == 9:
                self.check.same_state(a, b, f"after episode {episode}")
        self.check.same_state(a, b, f"after the {n} simulated episodes")
        return a, b, n

    # -- 4. adversarial transitions ----------------------------------------------------------------
    def check_refusals(self, learner: Learner, episode: int) -> None:
        """Invalid reports raise ValueError and change nothing (validated before applied)."""
        space = self.space
        ok = Transition(
            episode, 0, space.OBSERVE, space.INITIATE, -1.0, space.END, Polarity.NEGATIVE
        )
        bad = {
            "an action of another state": dataclasses.replace(ok, action=space.n_actions - 1),
            "a successor that cannot follow": dataclasses.replace(
                ok, next_state=space.ENGAGED + 1
            ),  # TYPE_KNOWN of the first service
            "a NaN reward": dataclasses.replace(ok, reward=math.nan),
            "an infinite reward": dataclasses.replace(ok, reward=math.inf),
            "episode 0": dataclasses.replace(ok, episode=0),
            "a context out of range": dataclasses.replace(ok, context=space.n_contexts),
            "a negative context": dataclasses.replace(ok, context=-1),
            "the END state": dataclasses.replace(ok, state=space.END),
        }
        before = canonical(self.check.export(learner))
        version = learner.version
        for why, tr in bad.items():
            self.check.expect_value_error(f"a report with {why}", learner.update, [ok, tr])
            if learner.version != version or canonical(self.check.export(learner)) != before:
                self.check.fail(
                    f"a refused report with {why} changed the learner (validate first)."
                )
        for obs, why in (
            (Observation(space.n_contexts, 0, 1), "a context out of range"),
            (Observation(0, space.END, 1), "the END state"),
            (Observation(0, 0, 0), "episode 0"),
        ):
            self.check.expect_value_error(
                f"select_action with {why}", learner.select_action, obs, self.check.rng(6)
            )

    def root_rejections(self, learner: Learner, episode: int, calls: int) -> int:
        sp, r = self.space, self.mission.rewards
        c = 0
        for _ in range(calls):
            episode += 1
            self.check.update(
                learner,
                [
                    Transition(
                        episode, c, sp.OBSERVE, sp.INITIATE, r.negative, sp.END, Polarity.NEGATIVE
                    )
                ],
            )
        return episode

    def accepted_services(self, learner: Learner, episode: int, calls: int) -> int:
        sp, r, mission = self.space, self.mission.rewards, self.mission
        c = min(1, sp.n_contexts - 1)
        service = mission.services[0]
        k, d = service.name, service.details[0]
        tk, dk = sp.type_known_state(k), sp.detail_known_state(k, d)
        infer_type = sp.action_index(Action(ActionKind.INFER_TYPE, k))
        infer_detail = sp.action_index(Action(ActionKind.INFER_DETAIL, k, d))
        perform = sp.action_index(Action(ActionKind.PERFORM, k, d))
        for _ in range(calls // 2):
            episode += 1
            self.check.update(
                learner,
                [
                    Transition(
                        episode,
                        c,
                        sp.OBSERVE,
                        sp.INITIATE,
                        r.positive,
                        sp.ENGAGED,
                        Polarity.POSITIVE,
                    )
                ],
            )
            self.check.update(
                learner,
                [
                    Transition(episode, c, sp.ENGAGED, infer_type, 0.0, tk),
                    Transition(episode, c, tk, infer_detail, 0.0, dk),
                    Transition(episode, c, dk, perform, r.max_step, sp.END, Polarity.POSITIVE),
                ],
            )
        return episode

    def wrong_services(self, learner: Learner, episode: int, calls: int) -> int:
        sp, r, mission = self.space, self.mission.rewards, self.mission
        c = min(2, sp.n_contexts - 1)
        service = mission.services[-1]
        k, d = service.name, service.details[-1]
        rq, tk, dk = sp.request_state(k), sp.type_known_state(k), sp.detail_known_state(k, d)
        respond_ = sp.action_index(Action(ActionKind.RESPOND, k))
        infer_detail = sp.action_index(Action(ActionKind.INFER_DETAIL, k, d))
        perform = sp.action_index(Action(ActionKind.PERFORM, k, d))
        for _ in range(calls // 2):
            episode += 1
            self.check.update(
                learner, [Transition(episode, c, sp.OBSERVE, sp.PASS, 0.0, rq, Polarity.POSITIVE)]
            )
            self.check.update(
                learner,
                [
                    Transition(episode, c, rq, respond_, r.positive, tk),
                    Transition(episode, c, tk, infer_detail, 0.0, dk),
                    Transition(episode, c, dk, perform, r.negative, sp.END, Polarity.NEGATIVE),
                ],
            )
        return episode

    def random_block(self, learner: Learner, episode: int, updates: int) -> int:
        """Random valid reports until ``updates`` calls were made; episodes jump far ahead."""
        space = self.space
        rng = self.check.rng(7)
        budget = max(0, updates - self.check.calls)
        start = self.check.calls
        jumps = [(start + budget // 3, _HUGE[0]), (start + 2 * budget // 3, _HUGE[1])]
        open_: list[list[list[Transition]]] = []  # per open episode, its remaining batches
        probe_every = max(1, budget // 25)
        while self.check.calls < updates:
            while jumps and self.check.calls >= jumps[0][0]:
                episode = max(episode, jumps.pop(0)[1])
            if len(open_) < 3 or rng.random() < 0.1:
                episode += 1
                context = int(rng.integers(space.n_contexts))
                batches = self.random_batches(rng, episode, context)
                if rng.random() < 0.25 and len(batches) > 1:
                    batches = batches[:1]  # a robot that vanished: the episode stays open
                open_.append(batches)
            i = int(rng.integers(len(open_)))
            self.check.update(learner, open_[i].pop(0))
            if not open_[i]:
                open_.pop(i)
            if (self.check.calls - start) % probe_every == 0:
                c = int(rng.integers(space.n_contexts))
                s = int(rng.integers(space.n_states))
                obs = Observation(c, s, episode + 1)
                self.check.decide(learner, obs, rng)
        return episode

    def random_batches(
        self, rng: np.random.Generator, episode: int, context: int
    ) -> list[list[Transition]]:
        space = self.space
        rows: list[Transition] = []
        state = space.OBSERVE
        while state != space.END:
            actions = space.actions_of(state)
            a = actions.start + int(rng.integers(len(actions)))
            succ = space.succ[a][space.succ_mask[a]]
            if len(succ) > 1 and rng.random() < 0.85:
                succ = succ[succ != space.END]  # mostly go on, so deep pairs get samples too
            nxt = int(succ[int(rng.integers(len(succ)))])
            reward = self.vocabulary[int(rng.integers(len(self.vocabulary)))]
            signal = Polarity(int(rng.integers(3)))
            rows.append(Transition(episode, context, state, a, reward, nxt, signal))
            state = nxt
        batches: list[list[Transition]] = []
        for row in rows:
            if batches and rng.random() < 0.5:
                batches[-1].append(row)
            else:
                batches.append([row])
        return batches

    def hot_contexts(self) -> list[int]:
        return sorted(
            {
                0,
                min(1, self.space.n_contexts - 1),
                min(2, self.space.n_contexts - 1),
                self.space.n_contexts - 1,
            }
        )

    # -- 5. checkpoints ----------------------------------------------------------------------------
    def checkpoint(self, learner: Learner, episode: int, contexts: Sequence[int]) -> Learner:
        """Check decisions, views and the export; return the imported clone to go on with."""
        space = self.space
        before = canonical(self.check.export(learner))
        rng = self.check.rng(8, episode % 2**32)
        for c in contexts:
            for s in range(space.n_states):
                obs = Observation(c, s, episode)
                self.check.decide(learner, obs, rng)
        for c in range(space.n_contexts):
            self.check.explain(learner, c, episode)
        if canonical(self.check.export(learner)) != before:
            self.check.fail("select_action or explain changed the learner's exported state.")
        return self.check.round_trip(learner, self.probes(episode, contexts))

    def final(self, learner: Learner, episode: int) -> None:
        space = self.space
        before = canonical(self.check.export(learner))
        rng = self.check.rng(9)
        now = episode + 1
        for e in (now, now + _HUGE[1], 1):  # current, far later, and an out-of-order old index
            for c in range(space.n_contexts):
                self.check.explain(learner, c, e)
            for c in self.hot_contexts():
                for s in range(space.n_states):
                    obs = Observation(c, s, e)
                    self.check.decide(learner, obs, rng)
        if canonical(self.check.export(learner)) != before:
            self.check.fail("select_action or explain changed the learner's exported state.")
        clone = self.check.round_trip(learner, self.probes(now, self.hot_contexts()))
        # The clone must go on learning exactly as the original does.
        tail = [Transition(now, 0, space.OBSERVE, space.PASS, 0.0, space.END)]
        self.check.update(learner, tail, count=False)
        self.check.update(clone, tail, count=False)
        self.check.same_state(learner, clone, "an imported clone after one more update")

    # -- observations to probe with ----------------------------------------------------------------
    def probes(
        self, episode: int, contexts: Sequence[int], *, state: int | None = None
    ) -> list[Observation]:
        states = [self.space.OBSERVE, self.space.ENGAGED] if state is None else [state]
        return [Observation(c, s, episode) for c in contexts for s in states]


def _bad_values(default: object) -> list[tuple[object, str]]:
    """Values a parameter with this default must refuse, each with the reason."""
    if isinstance(default, bool):
        return [(1, "a number, not true or false"), ("yes", "a string, not true or false")]
    if isinstance(default, int):
        return [
            ("3", "a string, not a whole number"),
            (2.5, "not a whole number"),
            (True, "a boolean, not a whole number"),
            (-1, "below the range"),
            (10**12, "above the range"),
        ]
    if isinstance(default, float):
        return [
            ("0.5", "a string, not a number"),
            (None, "not a number"),
            (True, "a boolean, not a number"),
            (math.nan, "NaN"),
            (math.inf, "infinite"),
            (-1e12, "below the range"),
            (1e12, "above the range"),
        ]
    if isinstance(default, str):
        return [(3, "not a string"), ("no_such_option", "not one of the allowed values")]
    return [(object(), "an arbitrary object")]
