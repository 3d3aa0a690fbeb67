"""The conformance suite every learner must pass: :func:`check_learner`.

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

The suite uses numpy and the standard library only, so it runs wherever the learning core does.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import math
import zlib
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NoReturn

import numpy as np

from .config import PARAMS
from .learners import learner_from_state, make_learner
from .mission import Mission
from .protocols import Learner
from .simulation import STEP_COLUMNS, drift, event_stream, random_profile, respond
from .space import Action, ActionKind, NegotiationSpace
from .types import ContextView, Decision, Observation, Polarity, Transition

__all__ = ["check_learner"]

_SIM_EPISODES = 60  # simulated-user episodes of phase 3 (about 150 update calls)
_HUGE = (10**9, 10**12)  # the episode indices of the staleness jumps
_TOL = 1e-9  # how far a distribution's sum may stray from 1


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
    def __init__(
        self, algorithm: str, mission: Mission, params: Mapping[str, Any] | None, seed: int
    ) -> None:
        self.algorithm = algorithm
        self.mission = mission
        self.params = dict(params or {})
        self.seed = seed
        self.label = algorithm + (f" {self.params}" if self.params else "")
        self.phase = "setup"
        self.calls = 0  # update calls made on the stressed learner
        first = make_learner(algorithm, self.params, mission)  # ValueError on bad input
        self.space: NegotiationSpace = first.space
        r = mission.rewards
        self.vocabulary = (
            0.0, r.positive, r.negative, r.query, r.query + r.negative, r.max_step,
        )

    # -- reporting -----------------------------------------------------------------------------
    def fail(self, message: str) -> NoReturn:
        raise AssertionError(
            f"check_learner({self.label}), {self.phase}: {message} (seed {self.seed})"
        )

    def make(self) -> Learner:
        return make_learner(self.algorithm, self.params, self.mission)

    def rng(self, *words: int) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence([self.seed, *words]))

    # -- the phases ----------------------------------------------------------------------------
    def run(self, updates: int) -> None:
        self.phase = "parameter validation"
        self.check_params()

        self.phase = "fresh learner"
        a, b = self.make(), self.make()
        self.check_fresh(a)

        self.phase = "simulated user"
        a, b, episode = self.simulated(a, b)
        a = self.checkpoint(a, episode + 1, contexts=range(min(4, self.space.n_contexts)))

        self.phase = "adversarial transitions"
        self.check_refusals(a, episode + 1)
        budget = max(0, updates - self.calls)
        plan = [
            ("identical root rejections", 0.2, self.root_rejections),
            ("identical accepted services", 0.4, self.accepted_services),
            ("identical wrong services", 0.1, self.wrong_services),
        ]
        for name, share, block in plan:
            self.phase = name
            episode = block(a, episode, int(budget * share))
            a = self.checkpoint(a, episode + 1, contexts=self.hot_contexts())
        self.phase = "random adversarial transitions with staleness jumps"
        episode = self.random_block(a, episode, updates)
        self.phase = "final checks"
        self.final(a, episode)

    # -- 1. parameters -------------------------------------------------------------------------
    def check_params(self) -> None:
        cls = PARAMS[self.algorithm]
        defaults = cls()
        for f in dataclasses.fields(cls):
            for bad, why in _bad_values(getattr(defaults, f.name)):
                try:
                    make_learner(self.algorithm, {f.name: bad}, self.mission)
                except ValueError as exc:
                    if f.name not in str(exc):
                        self.fail(
                            f"{f.name}={bad!r} ({why}) was refused, but the message does not "
                            f"name the parameter: {exc}"
                        )
                except Exception as exc:  # noqa: BLE001 - any other exception is the finding
                    self.fail(
                        f"{f.name}={bad!r} ({why}) raised {type(exc).__name__} instead of "
                        f"ValueError: {exc}"
                    )
                else:
                    self.fail(f"{f.name}={bad!r} ({why}) was accepted; it must be refused.")
        try:
            make_learner(self.algorithm, {"no_such_parameter": 1}, self.mission)
        except ValueError as exc:
            if "no_such_parameter" not in str(exc):
                self.fail(f"an unknown parameter was refused without naming it: {exc}")
        except Exception as exc:  # noqa: BLE001 - any other exception is the finding
            self.fail(f"an unknown parameter raised {type(exc).__name__}, not ValueError: {exc}")
        else:
            self.fail("an unknown parameter (no_such_parameter) was accepted.")

    # -- 2. fresh learner ----------------------------------------------------------------------
    def check_fresh(self, learner: Learner) -> None:
        if learner.algorithm != self.algorithm:
            self.fail(f"the learner calls itself {learner.algorithm!r}.")
        if learner.version != 0:
            self.fail(f"a fresh learner has version {learner.version}, expected 0.")
        want = PARAMS[self.algorithm].from_dict(self.params)
        if learner.params != want:
            self.fail(f"the learner holds params {learner.params!r}, expected {want!r}.")
        for c in range(self.space.n_contexts):
            self.check_view(learner, c, 1)
        self.round_trip(learner, self.probes(1, range(min(4, self.space.n_contexts))))

    # -- 3. simulated user, two learners in lockstep -------------------------------------------
    def simulated(self, a: Learner, b: Learner) -> tuple[Learner, Learner, int]:
        space, mission = self.space, self.mission
        n = _SIM_EPISODES
        before = random_profile(mission, self.rng(1))
        after = drift(before, mission, self.rng(2))
        change = n // 2
        contexts = event_stream([before, after], [0, change], mission, n, self.rng(3))
        uniforms = self.rng(4).random((n, STEP_COLUMNS))
        rng_a, rng_b = self.rng(5), self.rng(5)
        for e in range(n):
            episode, context = e + 1, int(contexts[e])
            profile = before if e < change else after
            state, step = space.OBSERVE, 0
            while state != space.END:
                if 2 * step + 2 > STEP_COLUMNS:
                    self.fail(f"episode {episode} did not end after {step} visible actions.")
                obs = Observation(context, state, episode)
                da = self.decide(a, obs, rng_a)
                db = self.decide(b, obs, rng_b)
                self.same_decision(da, db, f"two learners with the same seed, {self.at(obs)}")
                batch = da.chain_transitions(episode)
                reaction = respond(space, profile, context, da.state, da.action,
                                   uniforms[e, 2 * step : 2 * step + 2])
                batch.append(Transition(episode, context, da.state, da.action, reaction.reward,
                                        reaction.next_state, reaction.signal))
                self.update(a, batch)
                self.update(b, batch, count=False)
                state, step = reaction.next_state, step + 1
                if e % 12 == 5 and step == 1 and state != space.END:
                    # Mid-episode: the open episode's samples must travel with the export.
                    b = self.round_trip(b, self.probes(episode, [context], state=state))
            if e % 10 == 9:
                self.same_state(a, b, f"after episode {episode}")
        self.same_state(a, b, f"after the {n} simulated episodes")
        return a, b, n

    # -- 4. adversarial transitions ------------------------------------------------------------
    def check_refusals(self, learner: Learner, episode: int) -> None:
        """Invalid reports raise ValueError and change nothing (validated before applied)."""
        space = self.space
        ok = Transition(episode, 0, space.OBSERVE, space.INITIATE, -1.0, space.END,
                        Polarity.NEGATIVE)
        bad = {
            "an action of another state": dataclasses.replace(ok, action=space.n_actions - 1),
            "a successor that cannot follow": dataclasses.replace(
                ok, next_state=space.ENGAGED + 1),  # TYPE_KNOWN of the first service
            "a NaN reward": dataclasses.replace(ok, reward=math.nan),
            "an infinite reward": dataclasses.replace(ok, reward=math.inf),
            "episode 0": dataclasses.replace(ok, episode=0),
            "a context out of range": dataclasses.replace(ok, context=space.n_contexts),
            "a negative context": dataclasses.replace(ok, context=-1),
            "the END state": dataclasses.replace(ok, state=space.END),
        }
        before = _canonical(self.export(learner))
        version = learner.version
        for why, tr in bad.items():
            self.expect_value_error(f"a report with {why}", learner.update, [ok, tr])
            if learner.version != version or _canonical(self.export(learner)) != before:
                self.fail(f"a refused report with {why} changed the learner (validate first).")
        for obs, why in ((Observation(space.n_contexts, 0, 1), "a context out of range"),
                         (Observation(0, space.END, 1), "the END state"),
                         (Observation(0, 0, 0), "episode 0")):
            self.expect_value_error(f"select_action with {why}", learner.select_action, obs,
                                    self.rng(6))

    def expect_value_error(self, what: str, call: Callable[..., object], *args: Any) -> None:
        """``call(*args)`` must raise ValueError: another exception or none is a finding."""
        try:
            call(*args)
        except ValueError:
            return
        except Exception as exc:  # noqa: BLE001 - any other exception is the finding
            self.fail(f"{what} raised {type(exc).__name__}, not ValueError: {exc}")
        self.fail(f"{what} was accepted; it must raise ValueError.")

    def root_rejections(self, learner: Learner, episode: int, calls: int) -> int:
        sp, r = self.space, self.mission.rewards
        c = 0
        for _ in range(calls):
            episode += 1
            self.update(learner, [Transition(episode, c, sp.OBSERVE, sp.INITIATE, r.negative,
                                             sp.END, Polarity.NEGATIVE)])
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
            self.update(learner, [Transition(episode, c, sp.OBSERVE, sp.INITIATE, r.positive,
                                             sp.ENGAGED, Polarity.POSITIVE)])
            self.update(learner, [
                Transition(episode, c, sp.ENGAGED, infer_type, 0.0, tk),
                Transition(episode, c, tk, infer_detail, 0.0, dk),
                Transition(episode, c, dk, perform, r.max_step, sp.END, Polarity.POSITIVE),
            ])
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
            self.update(learner, [Transition(episode, c, sp.OBSERVE, sp.PASS, 0.0, rq,
                                             Polarity.POSITIVE)])
            self.update(learner, [
                Transition(episode, c, rq, respond_, r.positive, tk),
                Transition(episode, c, tk, infer_detail, 0.0, dk),
                Transition(episode, c, dk, perform, r.negative, sp.END, Polarity.NEGATIVE),
            ])
        return episode

    def random_block(self, learner: Learner, episode: int, updates: int) -> int:
        """Random valid reports until ``updates`` calls were made; episodes jump far ahead."""
        space = self.space
        rng = self.rng(7)
        budget = max(0, updates - self.calls)
        jumps = [(self.calls + budget // 3, _HUGE[0]), (self.calls + 2 * budget // 3, _HUGE[1])]
        open_: list[list[list[Transition]]] = []  # per open episode, its remaining batches
        probe_every = max(1, budget // 25)
        start = self.calls
        while self.calls < updates:
            while jumps and self.calls >= jumps[0][0]:
                episode = max(episode, jumps.pop(0)[1])
            if len(open_) < 3 or rng.random() < 0.1:
                episode += 1
                context = int(rng.integers(space.n_contexts))
                batches = self.random_batches(rng, episode, context)
                if rng.random() < 0.25 and len(batches) > 1:
                    batches = batches[:1]  # a robot that vanished: the episode stays open
                open_.append(batches)
            i = int(rng.integers(len(open_)))
            self.update(learner, open_[i].pop(0))
            if not open_[i]:
                open_.pop(i)
            if (self.calls - start) % probe_every == 0:
                c = int(rng.integers(space.n_contexts))
                s = int(rng.integers(space.n_states))
                obs = Observation(c, s, episode + 1)
                self.decide(learner, obs, rng)
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
        return sorted({0, min(1, self.space.n_contexts - 1), min(2, self.space.n_contexts - 1),
                       self.space.n_contexts - 1})

    # -- 5. checkpoints ------------------------------------------------------------------------
    def checkpoint(self, learner: Learner, episode: int, contexts: Sequence[int]) -> Learner:
        """Check decisions, views and the export; return the imported clone to go on with."""
        space = self.space
        before = _canonical(self.export(learner))
        rng = self.rng(8, episode % 2**32)
        for c in contexts:
            for s in range(space.n_states):
                obs = Observation(c, s, episode)
                self.decide(learner, obs, rng)
        for c in range(space.n_contexts):
            self.check_view(learner, c, episode)
        if _canonical(self.export(learner)) != before:
            self.fail("select_action or explain changed the learner's exported state.")
        return self.round_trip(learner, self.probes(episode, contexts))

    def final(self, learner: Learner, episode: int) -> None:
        space = self.space
        before = _canonical(self.export(learner))
        rng = self.rng(9)
        now = episode + 1
        for e in (now, now + _HUGE[1], 1):  # current, far later, and an out-of-order old index
            for c in range(space.n_contexts):
                self.check_view(learner, c, e)
            for c in self.hot_contexts():
                for s in range(space.n_states):
                    obs = Observation(c, s, e)
                    self.decide(learner, obs, rng)
        if _canonical(self.export(learner)) != before:
            self.fail("select_action or explain changed the learner's exported state.")
        clone = self.round_trip(learner, self.probes(now, self.hot_contexts()))
        # The clone must go on learning exactly as the original does.
        tail = [Transition(now, 0, space.OBSERVE, space.PASS, 0.0, space.END)]
        self.update(learner, tail, count=False)
        self.update(clone, tail, count=False)
        self.same_state(learner, clone, "an imported clone after one more update")

    # -- the individual checks -----------------------------------------------------------------
    def update(self, learner: Learner, batch: Sequence[Transition], *, count: bool = True) -> None:
        version = learner.version
        try:
            learner.update(batch)
        except Exception as exc:  # noqa: BLE001 - any exception on a valid report is the finding
            self.fail(f"update #{self.calls + 1} of a valid report raised "
                      f"{type(exc).__name__}: {exc}")
        if learner.version != version + 1:
            self.fail(
                f"update #{self.calls + 1} moved version from {version} to {learner.version}; "
                "each update call must add exactly one."
            )
        if count:
            self.calls += 1

    def decide(self, learner: Learner, obs: Observation, rng: np.random.Generator) -> Decision:
        """``select_action`` on a valid observation, checked."""
        try:
            d = learner.select_action(obs, rng)
        except Exception as exc:  # noqa: BLE001 - any exception is the finding
            self.fail(f"{self.at(obs)}: select_action raised {type(exc).__name__}: {exc}")
        self.check_decision(d, obs)
        return d

    def export(self, learner: Learner) -> dict[str, Any]:
        try:
            return learner.to_state()
        except Exception as exc:  # noqa: BLE001 - any exception is the finding
            self.fail(f"to_state raised {type(exc).__name__}: {exc}")

    def at(self, obs: Observation) -> str:
        return (f"episode {obs.episode}, context {obs.context}, "
                f"state {self.space.state_name(obs.state)}")

    def check_probabilities(self, probs: object, state: int, action: int, what: str) -> None:
        actions = self.space.actions_of(state)
        arr = np.asarray(probs)
        if arr.shape != (len(actions),):
            self.fail(f"{what}: probabilities have shape {arr.shape}, expected "
                      f"({len(actions)},) for the actions of {self.space.state_name(state)}.")
        if arr.dtype.kind != "f":
            self.fail(f"{what}: probabilities have dtype {arr.dtype}, expected floats.")
        if not np.all(np.isfinite(arr)):
            self.fail(f"{what}: probabilities are not finite: {arr.tolist()}.")
        if np.any(arr < 0):
            self.fail(f"{what}: probabilities are negative: {arr.tolist()}.")
        total = float(arr.sum())
        if abs(total - 1.0) > _TOL:
            self.fail(f"{what}: probabilities sum to {total!r}, not 1: {arr.tolist()}.")
        if action in actions and arr[action - actions.start] <= 0.0:
            self.fail(f"{what}: {self.space.action_name(action)} was chosen with probability 0.")

    def check_decision(self, d: Decision, obs: Observation) -> None:
        space, where = self.space, self.at(obs)
        if not isinstance(d, Decision):
            self.fail(f"{where}: select_action returned {type(d).__name__}, not a Decision.")
        if d.context != obs.context:
            self.fail(f"{where}: the decision is for context {d.context}.")
        state = obs.state
        for i, step in enumerate(d.chain):
            what = f"{where}, chain step {i}"
            if step.state != state:
                self.fail(f"{what} starts in {space.state_name(step.state)}, expected "
                          f"{space.state_name(state)}.")
            self.check_probabilities(step.probabilities, step.state, step.action, what)
            if not space.is_valid(step.state, step.action):
                self.fail(f"{what}: action {step.action} is not available in "
                          f"{space.state_name(step.state)}.")
            if not space.silent[step.action]:
                self.fail(f"{what}: {space.action_name(step.action)} needs the person; a chain "
                          "step must be silent.")
            if step.next_state != int(space.silent_next[step.action]):
                self.fail(f"{what}: {space.action_name(step.action)} leads to "
                          f"{space.state_name(int(space.silent_next[step.action]))}, not "
                          f"{space.state_name(step.next_state)}.")
            if step.reward != float(space.silent_reward[step.action]):
                self.fail(f"{what}: reward {step.reward!r}, the mission says "
                          f"{float(space.silent_reward[step.action])!r}.")
            state = step.next_state
        if d.state != state:
            self.fail(f"{where}: the decision is in {space.state_name(d.state)}, but its chain "
                      f"ends in {space.state_name(state)}.")
        if not 0 <= d.state < space.n_states:
            self.fail(f"{where}: the decision's state {d.state} is not a state of the mission.")
        self.check_probabilities(d.probabilities, d.state, d.action, where)
        if not space.is_valid(d.state, d.action):
            self.fail(f"{where}: action {d.action} is not available in "
                      f"{space.state_name(d.state)}.")
        if space.silent[d.action]:
            self.fail(f"{where}: the visible action {space.action_name(d.action)} is silent.")

    def check_view(self, learner: Learner, context: int, episode: int) -> None:
        space = self.space
        where = f"explain(context {context}, episode {episode})"
        try:
            view = learner.explain(context, episode)
        except Exception as exc:  # noqa: BLE001 - any exception is the finding
            self.fail(f"{where} raised {type(exc).__name__}: {exc}")
        if not isinstance(view, ContextView):
            self.fail(f"{where} returned {type(view).__name__}, not a ContextView.")
        fields: dict[str, Any] = {
            "q": view.q, "visits": view.visits, "kept_visits": view.kept_visits,
            "since_last": view.since_last, "measure": view.measure,
            "probabilities": view.probabilities,
        }
        for name, value in fields.items():
            if value is None and name in ("kept_visits", "measure"):
                continue
            arr = np.asarray(value)
            if arr.shape != (space.n_actions,):
                self.fail(f"{where}.{name} has shape {arr.shape}, expected ({space.n_actions},).")
            if arr.dtype.kind not in "fiu":
                self.fail(f"{where}.{name} has dtype {arr.dtype}, expected numbers.")
            if not np.all(np.isfinite(arr)):
                self.fail(f"{where}.{name} holds NaN or infinity at pairs "
                          f"{np.flatnonzero(~np.isfinite(arr)).tolist()}.")
        if np.any(np.asarray(view.visits) < 0):
            self.fail(f"{where}.visits holds negative counts.")
        probs = np.asarray(view.probabilities)
        for s in range(space.n_states):
            sl = slice(space.actions_of(s).start, space.actions_of(s).stop)
            total = float(probs[sl].sum())
            if np.any(probs[sl] < 0):
                self.fail(f"{where}.probabilities of {space.state_name(s)} are negative: "
                          f"{probs[sl].tolist()}.")
            if abs(total - 1.0) > _TOL:
                self.fail(f"{where}.probabilities of {space.state_name(s)} sum to {total!r}, "
                          f"not 1: {probs[sl].tolist()}.")

    def check_export(self, doc: Mapping[str, Any]) -> str:
        """The document as strict JSON text; every exported array finite."""
        try:
            text = json.dumps(doc, allow_nan=False, sort_keys=True)
        except (TypeError, ValueError) as exc:
            self.fail(f"to_state() is not plain, finite JSON: {exc}")
        arrays = doc.get("arrays")
        if not isinstance(arrays, Mapping):
            self.fail("to_state() has no 'arrays' object.")
        for name, enc in arrays.items():
            try:
                raw = zlib.decompress(base64.b64decode(enc["data"]))
                arr = np.frombuffer(raw, dtype=np.dtype(enc["dtype"]))
            except (KeyError, TypeError, ValueError, zlib.error) as exc:
                self.fail(f"exported array {name} cannot be decoded: {exc}")
            if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
                self.fail(f"exported array {name} holds NaN or infinity.")
        return text

    def round_trip(self, learner: Learner, probes: Sequence[Observation]) -> Learner:
        doc = self.export(learner)
        text = self.check_export(doc)
        try:
            clone: Learner = learner_from_state(json.loads(text), self.mission)
        except Exception as exc:  # noqa: BLE001 - any exception is the finding
            self.fail(f"importing the learner's own export raised {type(exc).__name__}: {exc}")
        if clone.version != learner.version:
            self.fail(f"the imported learner has version {clone.version}, the exported one "
                      f"{learner.version}.")
        again = self.export(clone)
        if _canonical(again) != text:
            self.fail("export -> import -> export differs in "
                      f"{', '.join(_differences(doc, again))}.")
        for i, obs in enumerate(probes):
            d1 = self.decide(learner, obs, self.rng(10, i))
            d2 = self.decide(clone, obs, self.rng(10, i))
            self.same_decision(d1, d2, f"an imported learner, {self.at(obs)}")
        return clone

    def same_decision(self, d1: Decision, d2: Decision, where: str) -> None:
        sp = self.space
        if (d1.context, d1.state, d1.action) != (d2.context, d2.state, d2.action):
            self.fail(f"{where}: decided {sp.action_name(d2.action)} in "
                      f"{sp.state_name(d2.state)}, expected {sp.action_name(d1.action)} in "
                      f"{sp.state_name(d1.state)}.")
        if not np.array_equal(d1.probabilities, d2.probabilities):
            self.fail(f"{where}: probabilities {np.asarray(d2.probabilities).tolist()} differ "
                      f"from {np.asarray(d1.probabilities).tolist()}.")
        steps1 = [(s.state, s.action, s.next_state, s.reward) for s in d1.chain]
        steps2 = [(s.state, s.action, s.next_state, s.reward) for s in d2.chain]
        if steps1 != steps2 or not all(
            np.array_equal(s1.probabilities, s2.probabilities)
            for s1, s2 in zip(d1.chain, d2.chain, strict=True)
        ):
            self.fail(f"{where}: the silent chains differ.")

    def same_state(self, a: Learner, b: Learner, where: str) -> None:
        da, db = self.export(a), self.export(b)
        if _canonical(da) != _canonical(db):
            self.fail(f"{where}: the exported states differ in "
                      f"{', '.join(_differences(da, db))}.")

    def probes(self, episode: int, contexts: Sequence[int], *, state: int | None = None
               ) -> list[Observation]:
        states = [self.space.OBSERVE, self.space.ENGAGED] if state is None else [state]
        return [Observation(c, s, episode) for c in contexts for s in states]


def _bad_values(default: object) -> list[tuple[object, str]]:
    """Values a parameter with this default must refuse, each with the reason."""
    if isinstance(default, bool):
        return [(1, "a number, not true or false"), ("yes", "a string, not true or false")]
    if isinstance(default, int):
        return [("3", "a string, not a whole number"), (2.5, "not a whole number"),
                (True, "a boolean, not a whole number"), (-1, "below the range"),
                (10**12, "above the range")]
    if isinstance(default, float):
        return [("0.5", "a string, not a number"), (None, "not a number"),
                (True, "a boolean, not a number"), (math.nan, "NaN"), (math.inf, "infinite"),
                (-1e12, "below the range"), (1e12, "above the range")]
    if isinstance(default, str):
        return [(3, "not a string"), ("no_such_option", "not one of the allowed values")]
    return [(object(), "an arbitrary object")]


def _canonical(doc: Mapping[str, Any]) -> str:
    return json.dumps(doc, sort_keys=True)


def _differences(a: Mapping[str, Any], b: Mapping[str, Any]) -> list[str]:
    out = []
    for key in sorted(set(a) | set(b)):
        va, vb = a.get(key), b.get(key)
        if _canonical({"v": va}) == _canonical({"v": vb}):
            continue
        if isinstance(va, Mapping) and isinstance(vb, Mapping):
            out += [f"{key}.{sub}" for sub in _differences(va, vb)]
        else:
            out.append(key)
    return out
