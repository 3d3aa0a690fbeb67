"""What every tabular learner shares: bookkeeping, the silent-step loop, validation and export.

Subclasses declare their tables (``_tables``), learn from single transitions (``_observe``) or
from whole episodes once they close (``_close``), take delayed explicit feedback on an executed
pair (``_reinforce``), and turn a context into a plan (``_plan``) and a plan into an action
distribution (``_policy``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Iterator, Mapping, Sequence
from typing import Any, ClassVar, Generic, Self, TypeVar

import numpy as np

from ..changes import ContextChange
from ..config import Params
from ..guidance import Guidance, Rule, guidance_from_state
from ..masks import restrict
from ..mission import Mission
from ..planning import draw
from ..space import space_for
from ..state import FORMAT, FORMAT_VERSION, StateFormatError, decode_array, encode_array
from ..types import (
    ChainStep,
    ContextView,
    Decision,
    FloatArray,
    IntArray,
    Observation,
    Polarity,
    Transition,
)

__all__ = ["TabularLearner"]

P = TypeVar("P", bound=Params)
_ONE = np.ones(1, dtype=np.float64)
_ONE.setflags(write=False)


class TabularLearner(Generic[P]):
    """Base of the learners: per-context tables indexed (context, pair).

    Shared state, all exported:
        visits: (C, P) int64, raw executions n(s, a).
        last: (C, P) int64, user episode index of the last execution (0 = never).
        last_ctx: (C, P) int64, the context's episode count at the last execution.
        episodes: the highest episode index seen; pending: transitions of open episodes.
    The episodes begun per context (``ctx_count``) are the visits of the root pairs.
    """

    algorithm: ClassVar[str]
    params_type: ClassVar[type[Params]]
    _tables: ClassVar[dict[str, tuple[type, str]]] = {}  # name -> (dtype, shape code)
    # Reward-sum tables and the successor-count table whose sum over M counts their samples
    # (the sum's code is the count's code without M). When a mission change drops a successor
    # of a pair, its counts there leave and the sum is scaled to the samples kept, so the mean
    # reward stays what it was (app.learning.remap).
    _reward_sums: ClassVar[dict[str, str]] = {}
    # Tables an older state may lack (added later): they keep their initial value on import.
    _optional_tables: ClassVar[frozenset[str]] = frozenset()
    MAX_OPEN_EPISODES: ClassVar[int] = 256
    MAX_EPISODE: ClassVar[int] = 2**62  # keeps every episode arithmetic inside int64
    # Params that change only how the learner decides from its tables, never what it learns
    # (nor its Q): learners that differ only in them learn the same tables from the same
    # transitions, so one replay can answer for all of them (``deciding_as``).
    POLICY_PARAMS: ClassVar[frozenset[str]] = frozenset()

    def __init__(self, mission: Mission, params: P | None = None) -> None:
        self.mission = mission
        self.space = space_for(mission)
        chosen: Params = self.params_type() if params is None else params
        if not isinstance(chosen, self.params_type):
            raise ValueError(f"params for {self.algorithm} must be {self.params_type.__name__}.")
        self._params: P = chosen  # type: ignore[assignment]
        C, Pn = self.space.n_contexts, self.space.n_actions
        self.version = 0
        self.episodes = 0
        self.visits: IntArray = np.zeros((C, Pn), dtype=np.int64)
        self.last: IntArray = np.zeros((C, Pn), dtype=np.int64)
        self.last_ctx: IntArray = np.zeros((C, Pn), dtype=np.int64)
        self._pending: dict[int, list[Transition]] = {}
        self._cache: dict[int, Any] = {}
        self.guidance = Guidance()  # staff corrections in force (app.learning.guidance)
        # The changes the latest update decided (app.learning.changes); not part of the state.
        self.changes: tuple[ContextChange, ...] = ()
        self._decided: list[ContextChange] = []
        for name, (dtype, code) in self._tables.items():
            setattr(self, name, np.zeros(self._shape(code), dtype=dtype))
        self._init_tables()

    # -- subclass hooks ------------------------------------------------------------------------
    def _init_tables(self) -> None:
        """Fill tables whose initial value is not zero."""

    def _observe(self, tr: Transition) -> None:
        """Learn from one transition as it arrives."""

    def _close(self, rows: list[Transition]) -> None:
        """Learn from a whole episode once its last transition arrived (rows in order)."""

    def _reinforce(
        self, context: int, action: int, episode: int, reward: float, *, pending: bool
    ) -> None:
        """Add ``reward`` to what was learned from the sample of (context, action) in ``episode``.

        ``pending``: the episode is still open and its last row of that pair already carries the
        extra reward (learners that learn at close need nothing more); otherwise the sample was
        learned already (or its open rows were forgotten) and only the tables can take it.
        """

    def _plan(self, context: int, episode: int, rng: np.random.Generator | None) -> Any:
        """What ``_policy`` needs for one decision in ``context`` (by default: Q)."""
        return self._q(context)

    def _policy(self, plan: Any, context: int, state: int, episode: int) -> FloatArray:
        raise NotImplementedError

    def _compute_q(self, context: int, gamma: float | None = None) -> FloatArray:
        """Point estimate of Q for one context, (P,), from the tables, discounted by ``gamma``
        (None: the mission's, as the learner plans)."""
        raise NotImplementedError

    def _q(self, context: int) -> FloatArray:
        """``_compute_q``, cached per context until a hook drops the entry (``_cache.pop``)."""
        return self._cached_q(context, None)

    def _cached_q(self, context: int, gamma: float | None) -> FloatArray:
        """``_compute_q`` at ``gamma``; a context's entry holds one array per gamma asked, all
        dropped together."""
        entry = self._cache.get(context)
        if entry is None:
            entry = self._cache[context] = {}
        cached: FloatArray | None = entry.get(gamma)
        if cached is None:
            cached = self._compute_q(context, gamma)
            cached.setflags(write=False)
            entry[gamma] = cached
        return cached

    def _check_tables(self) -> None:
        """Raise ``StateFormatError`` if imported tables hold values no learner could produce."""

    def _kept_visits(self, context: int) -> FloatArray | None:
        return None

    def _measure(self, context: int, episode: int) -> FloatArray | None:
        return None

    @property
    def decides_changes(self) -> bool:
        """Whether the learner has a mechanism of its own that decides a context changed (its
        decisions are in :attr:`changes` after each update; docs/method.md §8, "Changes
        detected"). Learners without one leave it to the profile's belief
        (``app.learning.changes.ProfileWatch``)."""
        return False

    def _decide(self, change: ContextChange) -> None:
        """Record a change the update under way decided (subclasses call it from their hooks)."""
        self._decided.append(change)

    # -- the protocol --------------------------------------------------------------------------
    @property
    def params(self) -> P:
        return self._params

    def select_action(self, obs: Observation, rng: np.random.Generator) -> Decision:
        """Draw the robot's next visible action from ``obs``, following silent steps on the way."""
        self._check_observation(obs)
        space = self.space
        plan = self._plan(obs.context, obs.episode, rng)
        state = obs.state
        chain: list[ChainStep] = []
        while True:
            actions = space.actions_of(state)
            if len(actions) == 1:
                probs = _ONE
                action = actions.start
            else:
                probs = restrict(
                    space,
                    self.guidance,
                    obs.context,
                    state,
                    self._policy(plan, obs.context, state, obs.episode),
                )
                action = actions.start + draw(probs, rng)
            if not space.silent[action]:
                return Decision(obs.context, state, action, probs, tuple(chain))
            nxt = int(space.silent_next[action])
            chain.append(ChainStep(state, action, probs, nxt, float(space.silent_reward[action])))
            state = nxt

    def distributions(
        self, context: int, states: Sequence[int], episode: int, rng: np.random.Generator
    ) -> list[FloatArray]:
        """The distributions :meth:`select_action` would draw from in ``states`` of one decision
        (its silent steps' states, then the visible one), all from one plan drawn from ``rng``,
        each aligned with ``space.actions_of(state)``. Pure: what this learner would have done
        at each step of a decision another learner took (off-policy evaluation, docs/method.md
        §17)."""
        self._check_observation(Observation(context, self.space.OBSERVE, episode))
        plan = self._plan(context, episode, rng)
        out: list[FloatArray] = []
        for state in states:
            if len(self.space.actions_of(state)) == 1:
                out.append(_ONE)
                continue
            out.append(
                restrict(
                    self.space,
                    self.guidance,
                    context,
                    state,
                    self._policy(plan, context, state, episode),
                )
            )
        return out

    def learns_as(self, params: Params) -> bool:
        """Whether a learner of this algorithm with ``params`` learns exactly what this one
        learns from the same transitions: it differs at most in :attr:`POLICY_PARAMS`."""
        if params is self._params:
            return True
        if type(params) is not type(self._params):
            return False
        return all(
            f.name in self.POLICY_PARAMS or getattr(params, f.name) == getattr(self._params, f.name)
            for f in dataclasses.fields(params)
        )

    @contextlib.contextmanager
    def deciding_as(self, params: P) -> Iterator[Self]:
        """This learner deciding (``distributions``, ``action_values``) as if made with
        ``params``, for the ``with`` block: what a learner of those params that learned the same
        transitions would answer, without learning twice. ``params`` may differ only in
        :attr:`POLICY_PARAMS` (``learns_as``), or a ``ValueError``; nothing may be learned in
        the block."""
        if not self.learns_as(params):
            raise ValueError(
                f"{self.algorithm} params may differ only in "
                f"{', '.join(sorted(self.POLICY_PARAMS)) or 'nothing'} to decide as them."
            )
        kept = self._params
        self._params = params
        try:
            yield self
        finally:
            self._params = kept

    def action_values(self, context: int, *, gamma: float | None = None) -> FloatArray:
        """The learner's point estimate of Q in ``context``, (P,): the value of doing each pair
        and following the learner's model from there (the model behind a doubly robust
        estimate). ``gamma``: the discount of those values; None is the mission's, the one the
        learner plans with; 1.0 gives the plain sum of the rewards to the episode's end, the
        unit an off-policy estimate counts in (every mission's negotiation is acyclic and
        ends). A learner without a model (Q-learning) has only its own, discounted, values."""
        if gamma is None or gamma == self.mission.gamma:
            out: FloatArray = self._q(context).copy()
            return out
        if not 0.0 <= gamma <= 1.0:
            raise ValueError(f"gamma must be in [0, 1], got {gamma!r}.")
        return self._cached_q(context, float(gamma)).copy()

    @property
    def ctx_count(self) -> IntArray:
        """(C,) episodes begun per context: the visits of its root pairs."""
        out: IntArray = self.visits[:, list(self.space.root_actions)].sum(axis=1)
        return out

    def update(self, transitions: Sequence[Transition]) -> None:
        """Learn from the transitions one report resolved; the version goes up by one.

        Every transition is checked before anything changes: a ``ValueError`` leaves the learner
        as it was. An empty list changes nothing. Afterwards :attr:`changes` holds the contexts
        this update decided changed (``app.learning.changes.ContextChange``; empty for learners
        without a mechanism of their own, and after an empty list).
        """
        for tr in transitions:
            self._check_transition(tr)
        self._decided = []
        self.changes = ()
        if not transitions:
            return
        root = self.space.root_actions
        visits, last = self.visits, self.last
        for tr in transitions:
            c, a = tr.context, tr.action
            self.episodes = max(self.episodes, int(tr.episode))  # a plain int, for the state
            visits[c, a] += 1
            if last[c, a] < tr.episode:
                last[c, a] = tr.episode
            self.last_ctx[c, a] = sum(int(visits[c, r]) for r in root)
            self._observe(tr)
            if self.guidance:
                self.guidance.observe(self.space, tr)
            rows = self._pending.setdefault(tr.episode, [])
            rows.append(tr)
            if tr.next_state == self.space.END:
                self._close(self._pending.pop(tr.episode))
            elif len(self._pending) > self.MAX_OPEN_EPISODES:
                # An episode nobody closed (a robot that vanished): forget its open samples.
                del self._pending[min(self._pending)]
        self.changes = tuple(self._decided)
        self._decided = []
        self.version += 1

    def feedback(self, episode: int, context: int, action: int, reward: float) -> None:
        """Add an explicit feedback reward (a smile, a complaint) to the sample of ``action`` in
        ``episode``: its reward grows by ``reward``. The version goes up by one.

        The pair must have been executed and the episode seen; everything is checked first, and a
        ``ValueError`` leaves the learner as it was. While the episode is open, the last pending
        row of the pair in it carries the extra reward, so learners that learn at close see it as
        part of the sample; once closed, the learner adds it to its tables.
        """
        space = self.space
        _check_index("action", action, 0, space.n_actions)
        self._check_observation(Observation(context, int(space.pair_state[action]), episode))
        _check_reward(reward)
        if self.visits[context, action] == 0:
            raise ValueError(
                f"{space.action_name(action)} was never executed in context {context}: there "
                "is no sample to give feedback on."
            )
        if episode > self.episodes:
            raise ValueError(
                f"episode {episode} has not been seen yet (the last seen is {self.episodes})."
            )
        amount = float(reward)
        rows = self._pending.get(episode, [])
        hits = [i for i, row in enumerate(rows) if row.context == context and row.action == action]
        if hits:
            row = rows[hits[-1]]
            rows[hits[-1]] = dataclasses.replace(row, reward=row.reward + amount)
        self._reinforce(context, action, episode, amount, pending=bool(hits))
        self._cache.pop(context, None)
        self.version += 1

    def correct(self, rule: Rule) -> None:
        """Put a staff correction in force (``app.learning.guidance``); the version goes up by
        one. ``ValueError`` (nothing changes) if it does not fit the mission."""
        self.guidance.add(rule, self.mission)
        self.version += 1

    def lift(self, rule_id: str) -> None:
        """Take the correction ``rule_id`` out of force; the version goes up by one.
        ``KeyError`` if there is none of that id."""
        self.guidance.lift(rule_id)
        self.version += 1

    def explain(self, context: int, episode: int) -> ContextView:
        """What the learner believes in ``context`` if asked now, in episode ``episode``."""
        self._check_observation(Observation(context, 0, episode))
        plan = self._plan(context, episode, None)
        probs = np.empty(self.space.n_actions, dtype=np.float64)
        for s in range(self.space.n_states):
            actions = self.space.actions_of(s)
            if len(actions) == 1:
                probs[actions.start : actions.stop] = _ONE
                continue
            policy = restrict(
                self.space, self.guidance, context, s, self._policy(plan, context, s, episode)
            )
            probs[actions.start : actions.stop] = policy
        return ContextView(
            q=self._q(context).copy(),
            visits=self.visits[context].copy(),
            kept_visits=self._kept_visits(context),
            since_last=self.since_last(context, episode),
            measure=self._measure(context, episode),
            probabilities=probs,
        )

    def since_last(self, context: int, episode: int) -> IntArray:
        """t(s, a): episodes since each pair's last execution (never executed: ``episode``)."""
        out: IntArray = episode - self.last[context]
        return out

    # -- validation ----------------------------------------------------------------------------
    def _check_observation(self, obs: Observation) -> None:
        space = self.space
        _check_index("context", obs.context, 0, space.n_contexts)
        _check_index("state", obs.state, 0, space.n_states)
        _check_index("episode", obs.episode, 1, self.MAX_EPISODE)

    def _check_transition(self, tr: Transition) -> None:
        space = self.space
        context, state, episode, action = tr.context, tr.state, tr.episode, tr.action
        if (  # the common case, first: whole numbers in range, a real action of the state
            type(context) is int
            and type(state) is int
            and type(episode) is int
            and type(action) is int
            and type(tr.next_state) is int
            and 0 <= context < space.n_contexts
            and 0 <= state < space.n_states
            and 1 <= episode < self.MAX_EPISODE
            and action in space.actions_of(state)
            and space.can_follow(action, tr.next_state)
            and type(tr.reward) is float
            and math.isfinite(tr.reward)
            and type(tr.signal) in (Polarity, int)  # not a bool
            and tr.signal in (0, 1, 2)
        ):
            return
        self._check_observation(Observation(context, state, episode))
        _check_index("action", tr.action, 0, space.n_actions)
        if tr.action not in space.actions_of(tr.state):
            raise ValueError(
                f"action {tr.action} is not available in {space.state_name(tr.state)}."
            )
        _check_index("next_state", tr.next_state, 0, space.END + 1)
        space.successor_column(tr.action, tr.next_state)  # raises ValueError
        _check_reward(tr.reward)
        if tr.signal not in (0, 1, 2) or isinstance(tr.signal, bool):
            raise ValueError(f"signal must be a Polarity (0, 1 or 2), got {tr.signal!r}.")

    # -- export / import -----------------------------------------------------------------------
    def _shape(self, code: str) -> tuple[int, ...]:
        dims = {
            "C": self.space.n_contexts,
            "P": self.space.n_actions,
            "M": self.space.max_succ,
            "2": 2,
            "3": 3,
            "4": 4,
        }
        return tuple(dims[ch] for ch in code)

    def _exported(self) -> dict[str, tuple[np.ndarray, str]]:
        out = {
            "visits": (self.visits, "CP"),
            "last": (self.last, "CP"),
            "last_ctx": (self.last_ctx, "CP"),
        }
        for name, (_, code) in self._tables.items():
            out[name] = (getattr(self, name), code)
        return out

    def to_state(self) -> dict[str, Any]:
        """The learner as a self-describing JSON-ready document (see ``app.learning.state``)."""
        return {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "algorithm": self.algorithm,
            "params": self._params.to_dict(),
            "mission": {"name": self.mission.name, "fingerprint": self.mission.fingerprint},
            "version": self.version,
            "episodes": self.episodes,
            "arrays": {name: encode_array(arr) for name, (arr, _) in self._exported().items()},
            "pending": [
                [
                    int(t.episode),
                    int(t.context),
                    int(t.state),
                    int(t.action),
                    float(t.reward),
                    int(t.next_state),
                    int(t.signal),
                ]
                for rows in self._pending.values()
                for t in rows
            ],
            **({"guidance": [r.to_dict() for r in self.guidance.rules]} if self.guidance else {}),
        }

    @classmethod
    def from_state(cls, doc: Mapping[str, Any], mission: Mission) -> Self:
        """Rebuild a learner from ``to_state``'s document, or raise :class:`StateFormatError`."""
        if doc.get("format") != FORMAT:
            raise StateFormatError(f"format must be {FORMAT!r}, got {doc.get('format')!r}.")
        if doc.get("format_version") != FORMAT_VERSION:
            raise StateFormatError(
                f"format_version {doc.get('format_version')!r} is not supported (this service "
                f"reads version {FORMAT_VERSION})."
            )
        if doc.get("algorithm") != cls.algorithm:
            raise StateFormatError(
                f"algorithm must be {cls.algorithm!r}, got {doc.get('algorithm')!r}."
            )
        meta = doc.get("mission")
        if not isinstance(meta, Mapping) or meta.get("fingerprint") != mission.fingerprint:
            name = meta.get("name") if isinstance(meta, Mapping) else None
            raise StateFormatError(
                f"the state was learned for mission {name!r} with other services, situations or "
                f"rewards than the mission in force ({mission.name!r})."
            )
        if not isinstance(doc.get("params"), Mapping):
            raise StateFormatError("params must be an object naming the learner's parameters.")
        try:
            params = cls.params_type.from_dict(doc["params"])
        except (ValueError, TypeError, OverflowError) as exc:
            raise StateFormatError(f"params: {exc}") from None
        learner = cls(mission, params)  # type: ignore[arg-type]
        for field in ("version", "episodes"):
            value = doc.get(field)
            if (
                isinstance(value, bool)
                or not isinstance(value, int)
                or not 0 <= value < cls.MAX_EPISODE
            ):
                raise StateFormatError(f"{field} must be a whole number in [0, 2**62).")
            setattr(learner, field, value)
        arrays = doc.get("arrays")
        if not isinstance(arrays, Mapping):
            raise StateFormatError("arrays must be an object.")
        for name, (current, code) in learner._exported().items():
            if name not in arrays:
                if name in learner._optional_tables:
                    continue
                raise StateFormatError(f"arrays.{name} is missing.")
            value = decode_array(
                arrays[name], name=name, dtype=current.dtype, shape=learner._shape(code)
            )
            current[...] = value
        pending = doc.get("pending", [])
        if not isinstance(pending, list):
            raise StateFormatError("pending must be a list.")
        for i, row in enumerate(pending):
            try:
                ep, c, s, a, r, nxt, sig = row
                tr = Transition(int(ep), int(c), int(s), int(a), float(r), int(nxt), Polarity(sig))
                learner._check_transition(tr)
            except (TypeError, ValueError, OverflowError):
                raise StateFormatError(f"pending[{i}] is not a valid transition.") from None
            learner._pending.setdefault(tr.episode, []).append(tr)
        learner.guidance = guidance_from_state(doc.get("guidance"))
        learner._check_shared_tables()
        learner._check_tables()
        return learner

    def _check_shared_tables(self) -> None:
        if np.any(self.visits < 0):
            raise StateFormatError("arrays.visits must not be negative.")
        if np.any(self.last < 0) or np.any(self.last > self.episodes):
            raise StateFormatError("arrays.last must be between 0 and the episodes seen.")
        if np.any(self.last_ctx < 0) or np.any(self.last_ctx > self.ctx_count[:, None]):
            raise StateFormatError(
                "arrays.last_ctx must be between 0 and the context's episodes begun."
            )


def _check_index(name: str, value: object, low: int, high: int) -> None:
    """A whole number in [low, high), or a ValueError naming ``name``."""
    if type(value) is int and low <= value < high:
        return  # the common case, first (a bool's type is bool, not int)
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ValueError(f"{name} must be a whole number, got {value!r}.")
    if not low <= value < high:
        raise ValueError(f"{name} must be in [{low}, {high}), got {value}.")


def _check_reward(reward: object) -> None:
    """A finite real number (not a bool), or a ValueError."""
    if isinstance(reward, bool) or not isinstance(reward, int | float | np.floating):
        raise ValueError(f"reward must be a number, got {reward!r}.")
    try:
        finite = math.isfinite(float(reward))
    except OverflowError:  # an int too large for a float
        finite = False
    if not finite:
        raise ValueError(f"reward must be a finite number, got {reward!r}.")


def check_nonnegative(**tables: np.ndarray) -> None:
    """``StateFormatError`` naming the first table with a negative entry."""
    for name, table in tables.items():
        if np.any(table < 0):
            raise StateFormatError(f"arrays.{name} must not be negative.")
