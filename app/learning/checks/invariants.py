"""The per-call checks of the conformance suite: each wraps one call to a learner or inspects
what one call returned, and fails with a sentence.

:class:`CallChecks` makes one call (``update``, ``select_action``, ``explain``, ``to_state``, the
import of an export) and checks the learner's contract on it: ``update`` adds exactly one to
``version``; a decision's silent chain and visible action are valid, its distributions finite
and summing to one; every ``explain`` array finite and of the right shape; the export strict,
finite JSON that imports back identical; invalid input refused with ``ValueError``. It does not
choose what to call: the phased driver (:mod:`.suite`) does, and sets the phase the failures
name. Like the rest of the learning core it needs numpy and the standard library only.
"""

from __future__ import annotations

import base64
import json
import zlib
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NoReturn

import numpy as np

from ..learners import learner_from_state
from ..mission import Mission
from ..protocols import Learner
from ..space import NegotiationSpace
from ..types import ContextView, Decision, Observation, Transition

__all__ = ["CallChecks", "canonical"]

_TOL = 1e-9  # how far a distribution's sum may stray from 1


class CallChecks:
    """The per-call checks of one conformance run (one algorithm, its parameters, one seed).

    Every failure is an ``AssertionError``: ``check_learner(<label>), <phase>: <what> (seed
    <seed>)``. :attr:`phase` is set by the driver; :attr:`calls` counts the ``update`` calls
    made on the stressed learner.
    """

    def __init__(self, label: str, mission: Mission, space: NegotiationSpace, seed: int) -> None:
        self.label = label
        self.mission = mission
        self.space = space
        self.seed = seed
        self.phase = "setup"
        self.calls = 0  # update calls made on the stressed learner

    def fail(self, message: str) -> NoReturn:
        raise AssertionError(
            f"check_learner({self.label}), {self.phase}: {message} (seed {self.seed})"
        )

    def rng(self, *words: int) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence([self.seed, *words]))

    def at(self, obs: Observation) -> str:
        return (
            f"episode {obs.episode}, context {obs.context}, "
            f"state {self.space.state_name(obs.state)}"
        )

    # -- one call, checked -------------------------------------------------------------------------
    def update(self, learner: Learner, batch: Sequence[Transition], *, count: bool = True) -> None:
        version = learner.version
        try:
            learner.update(batch)
        except Exception as exc:  # any exception on a valid report is the finding
            self.fail(
                f"update #{self.calls + 1} of a valid report raised {type(exc).__name__}: {exc}"
            )
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
        except Exception as exc:  # any exception is the finding
            self.fail(f"{self.at(obs)}: select_action raised {type(exc).__name__}: {exc}")
        self.check_decision(d, obs)
        return d

    def export(self, learner: Learner) -> dict[str, Any]:
        try:
            return learner.to_state()
        except Exception as exc:  # any exception is the finding
            self.fail(f"to_state raised {type(exc).__name__}: {exc}")

    def explain(self, learner: Learner, context: int, episode: int) -> None:
        """``explain`` in one context, checked: one finite number per pair in every array, and a
        distribution summing to one in every state."""
        space = self.space
        where = f"explain(context {context}, episode {episode})"
        try:
            view = learner.explain(context, episode)
        except Exception as exc:  # any exception is the finding
            self.fail(f"{where} raised {type(exc).__name__}: {exc}")
        if not isinstance(view, ContextView):
            self.fail(f"{where} returned {type(view).__name__}, not a ContextView.")
        fields: dict[str, Any] = {
            "q": view.q,
            "visits": view.visits,
            "kept_visits": view.kept_visits,
            "since_last": view.since_last,
            "measure": view.measure,
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
                self.fail(
                    f"{where}.{name} holds NaN or infinity at pairs "
                    f"{np.flatnonzero(~np.isfinite(arr)).tolist()}."
                )
        if np.any(np.asarray(view.visits) < 0):
            self.fail(f"{where}.visits holds negative counts.")
        probs = np.asarray(view.probabilities)
        for s in range(space.n_states):
            sl = slice(space.actions_of(s).start, space.actions_of(s).stop)
            total = float(probs[sl].sum())
            if np.any(probs[sl] < 0):
                self.fail(
                    f"{where}.probabilities of {space.state_name(s)} are negative: "
                    f"{probs[sl].tolist()}."
                )
            if abs(total - 1.0) > _TOL:
                self.fail(
                    f"{where}.probabilities of {space.state_name(s)} sum to {total!r}, "
                    f"not 1: {probs[sl].tolist()}."
                )

    def round_trip(self, learner: Learner, probes: Sequence[Observation]) -> Learner:
        """Export, check the document, import it: the same version, an identical re-export and
        the same decisions on ``probes``. Returns the imported clone."""
        doc = self.export(learner)
        text = self.check_export(doc)
        try:
            clone: Learner = learner_from_state(json.loads(text), self.mission)
        except Exception as exc:  # any exception is the finding
            self.fail(f"importing the learner's own export raised {type(exc).__name__}: {exc}")
        if clone.version != learner.version:
            self.fail(
                f"the imported learner has version {clone.version}, the exported one "
                f"{learner.version}."
            )
        again = self.export(clone)
        if canonical(again) != text:
            self.fail(
                f"export -> import -> export differs in {', '.join(_differences(doc, again))}."
            )
        for i, obs in enumerate(probes):
            d1 = self.decide(learner, obs, self.rng(10, i))
            d2 = self.decide(clone, obs, self.rng(10, i))
            self.same_decision(d1, d2, f"an imported learner, {self.at(obs)}")
        return clone

    def expect_value_error(self, what: str, call: Callable[..., object], *args: Any) -> None:
        """``call(*args)`` must raise ValueError: another exception or none is a finding."""
        try:
            call(*args)
        except ValueError:
            return
        except Exception as exc:  # any other exception is the finding
            self.fail(f"{what} raised {type(exc).__name__}, not ValueError: {exc}")
        self.fail(f"{what} was accepted; it must raise ValueError.")

    # -- what one call returned --------------------------------------------------------------------
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
                self.fail(
                    f"{what} starts in {space.state_name(step.state)}, expected "
                    f"{space.state_name(state)}."
                )
            self.check_probabilities(step.probabilities, step.state, step.action, what)
            if not space.is_valid(step.state, step.action):
                self.fail(
                    f"{what}: action {step.action} is not available in "
                    f"{space.state_name(step.state)}."
                )
            if not space.silent[step.action]:
                self.fail(
                    f"{what}: {space.action_name(step.action)} needs the person; a chain "
                    "step must be silent."
                )
            if step.next_state != int(space.silent_next[step.action]):
                self.fail(
                    f"{what}: {space.action_name(step.action)} leads to "
                    f"{space.state_name(int(space.silent_next[step.action]))}, not "
                    f"{space.state_name(step.next_state)}."
                )
            if step.reward != float(space.silent_reward[step.action]):
                self.fail(
                    f"{what}: reward {step.reward!r}, the mission says "
                    f"{float(space.silent_reward[step.action])!r}."
                )
            state = step.next_state
        if d.state != state:
            self.fail(
                f"{where}: the decision is in {space.state_name(d.state)}, but its chain "
                f"ends in {space.state_name(state)}."
            )
        if not 0 <= d.state < space.n_states:
            self.fail(f"{where}: the decision's state {d.state} is not a state of the mission.")
        self.check_probabilities(d.probabilities, d.state, d.action, where)
        if not space.is_valid(d.state, d.action):
            self.fail(
                f"{where}: action {d.action} is not available in {space.state_name(d.state)}."
            )
        if space.silent[d.action]:
            self.fail(f"{where}: the visible action {space.action_name(d.action)} is silent.")

    def check_probabilities(self, probs: object, state: int, action: int, what: str) -> None:
        actions = self.space.actions_of(state)
        arr = np.asarray(probs)
        if arr.shape != (len(actions),):
            self.fail(
                f"{what}: probabilities have shape {arr.shape}, expected "
                f"({len(actions)},) for the actions of {self.space.state_name(state)}."
            )
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

    # -- two learners compared ---------------------------------------------------------------------
    def same_decision(self, d1: Decision, d2: Decision, where: str) -> None:
        sp = self.space
        if (d1.context, d1.state, d1.action) != (d2.context, d2.state, d2.action):
            self.fail(
                f"{where}: decided {sp.action_name(d2.action)} in "
                f"{sp.state_name(d2.state)}, expected {sp.action_name(d1.action)} in "
                f"{sp.state_name(d1.state)}."
            )
        if not np.array_equal(d1.probabilities, d2.probabilities):
            self.fail(
                f"{where}: probabilities {np.asarray(d2.probabilities).tolist()} differ "
                f"from {np.asarray(d1.probabilities).tolist()}."
            )
        steps1 = [(s.state, s.action, s.next_state, s.reward) for s in d1.chain]
        steps2 = [(s.state, s.action, s.next_state, s.reward) for s in d2.chain]
        if steps1 != steps2 or not all(
            np.array_equal(s1.probabilities, s2.probabilities)
            for s1, s2 in zip(d1.chain, d2.chain, strict=True)
        ):
            self.fail(f"{where}: the silent chains differ.")

    def same_state(self, a: Learner, b: Learner, where: str) -> None:
        da, db = self.export(a), self.export(b)
        if canonical(da) != canonical(db):
            self.fail(f"{where}: the exported states differ in {', '.join(_differences(da, db))}.")


def canonical(doc: Mapping[str, Any]) -> str:
    """``doc`` as JSON text with sorted keys: equal documents, equal texts."""
    return json.dumps(doc, sort_keys=True)


def _differences(a: Mapping[str, Any], b: Mapping[str, Any]) -> list[str]:
    out = []
    for key in sorted(set(a) | set(b)):
        va, vb = a.get(key), b.get(key)
        if canonical({"v": va}) == canonical({"v": vb}):
            continue
        if isinstance(va, Mapping) and isinstance(vb, Mapping):
            out += [f"{key}.{sub}" for sub in _differences(va, vb)]
        else:
            out.append(key)
    return out
