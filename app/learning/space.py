"""The service-negotiation MDP of a mission (docs/method.md §2), laid out for tables.

Per context there are ``L`` non-terminal local states, in this order::

    0                 OBSERVE             actions: initiate, pass
    1 .. K            REQUEST(k)          respond                      (silent)
    K+1               ENGAGED             query_type, infer_type(k)    (infer silent)
    K+2 .. 2K+1       TYPE_KNOWN(k)       query_detail, infer_detail(d) (infer silent)
    2K+2 .. L-1       DETAIL_KNOWN(k, d)  perform

and ``END = L`` is the absorbing terminal. The (state, action) *pairs* of a context are numbered
``0 .. P-1``, grouped by state in state order, so the actions of state ``s`` are the contiguous
range ``actions_of(s)``. Each pair has a fixed list of possible successors (``succ``, padded to
``M`` columns, END always among them); learners keep their counts per successor column.

Beyond the paper's negotiation (docs/method.md §2), ``pass`` may also lead to ENGAGED: a person
who addresses the robot without naming a service yet (an I1 episode whose type is still
unknown). The simulated users never do; the service's API allows it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from .mission import Mission
from .types import FloatArray, IntArray

__all__ = ["Action", "ActionKind", "NegotiationSpace", "StateInfo", "StateKind"]


class StateKind(StrEnum):
    OBSERVE = "OBSERVE"
    REQUEST = "REQUEST"
    ENGAGED = "ENGAGED"
    TYPE_KNOWN = "TYPE_KNOWN"
    DETAIL_KNOWN = "DETAIL_KNOWN"
    END = "END"


class ActionKind(StrEnum):
    INITIATE = "initiate"
    PASS = "pass"
    RESPOND = "respond"
    QUERY_TYPE = "query_type"
    INFER_TYPE = "infer_type"
    QUERY_DETAIL = "query_detail"
    INFER_DETAIL = "infer_detail"
    PERFORM = "perform"


SILENT_KINDS = frozenset({ActionKind.RESPOND, ActionKind.INFER_TYPE, ActionKind.INFER_DETAIL})
QUERY_KINDS = frozenset({ActionKind.QUERY_TYPE, ActionKind.QUERY_DETAIL})


@dataclass(frozen=True, slots=True)
class StateInfo:
    kind: StateKind
    service: str | None = None
    detail: str | None = None


@dataclass(frozen=True, slots=True)
class Action:
    kind: ActionKind
    service: str | None = None
    detail: str | None = None

    @property
    def silent(self) -> bool:
        return self.kind in SILENT_KINDS

    def to_dict(self) -> dict[str, str]:
        out = {"kind": self.kind.value}
        if self.service is not None:
            out["service"] = self.service
        if self.detail is not None:
            out["detail"] = self.detail
        return out


class NegotiationSpace:
    """States, actions and structural successors of a mission's negotiation, per context.

    Attributes (all read-only):
        n_contexts (C), n_states (L, non-terminal), END (== L), n_actions (P), max_succ (M).
        pair_state: (P,) int64, the state of each pair.
        state_start: (L,) int64, first pair of each state; state_count: (L,) pairs per state.
        succ: (P, M) int64 successor local states (padding repeats END); succ_mask: (P, M) bool.
        silent: (P,) bool; silent_next: (P,) next state of a silent pair (-1 otherwise);
        silent_reward: (P,) float64 reward of a silent pair.
        root_actions: pairs of OBSERVE, (initiate, pass).
        unavailable: (C,) bool, the contexts of the mission's unavailable situations.
    """

    def __init__(self, mission: Mission) -> None:
        self.mission = mission
        services = mission.services
        K = len(services)
        self.n_contexts = mission.n_contexts
        states: list[StateInfo] = [StateInfo(StateKind.OBSERVE)]
        states += [StateInfo(StateKind.REQUEST, s.name) for s in services]
        states.append(StateInfo(StateKind.ENGAGED))
        states += [StateInfo(StateKind.TYPE_KNOWN, s.name) for s in services]
        detail_state: dict[tuple[int, int], int] = {}
        for k, s in enumerate(services):
            for d, detail in enumerate(s.details):
                detail_state[(k, d)] = len(states)
                states.append(StateInfo(StateKind.DETAIL_KNOWN, s.name, detail))
        self.states: tuple[StateInfo, ...] = tuple(states)
        self.n_states = L = len(states)
        self.END = L
        self.OBSERVE = 0
        self.ENGAGED = K + 1
        request = [1 + k for k in range(K)]
        type_known = [K + 2 + k for k in range(K)]

        actions: list[Action] = []
        pair_state: list[int] = []
        succ: list[list[int]] = []
        silent_next: list[int] = []
        rewards = mission.rewards

        def add(state: int, action: Action, successors: list[int], nxt: int = -1) -> None:
            actions.append(action)
            pair_state.append(state)
            succ.append([*successors, L])
            silent_next.append(nxt)

        add(0, Action(ActionKind.INITIATE), [self.ENGAGED])
        add(0, Action(ActionKind.PASS), [*request, self.ENGAGED])
        for k, s in enumerate(services):
            add(request[k], Action(ActionKind.RESPOND, s.name), [type_known[k]], type_known[k])
        add(self.ENGAGED, Action(ActionKind.QUERY_TYPE), type_known)
        for k, s in enumerate(services):
            add(self.ENGAGED, Action(ActionKind.INFER_TYPE, s.name), [type_known[k]], type_known[k])
        for k, s in enumerate(services):
            details = [detail_state[(k, d)] for d in range(len(s.details))]
            add(type_known[k], Action(ActionKind.QUERY_DETAIL, s.name), details)
            for d, detail in enumerate(s.details):
                add(
                    type_known[k],
                    Action(ActionKind.INFER_DETAIL, s.name, detail),
                    [details[d]],
                    details[d],
                )
        for k, s in enumerate(services):
            for d, detail in enumerate(s.details):
                add(detail_state[(k, d)], Action(ActionKind.PERFORM, s.name, detail), [])

        self.actions: tuple[Action, ...] = tuple(actions)
        self.n_actions = P = len(actions)
        self.max_succ = M = max(len(row) for row in succ)
        self.pair_state: IntArray = np.asarray(pair_state, dtype=np.int64)
        self.state_start: IntArray = np.searchsorted(self.pair_state, np.arange(L)).astype(np.int64)
        self.state_count: IntArray = np.bincount(self.pair_state, minlength=L).astype(np.int64)
        self.succ: IntArray = np.full((P, M), L, dtype=np.int64)
        self.succ_mask = np.zeros((P, M), dtype=bool)
        for p, row in enumerate(succ):
            self.succ[p, : len(row)] = row
            self.succ_mask[p, : len(row)] = True
        self.end_column: IntArray = np.asarray([len(row) - 1 for row in succ], dtype=np.int64)
        # The transition of a pair that ends the episode: all its mass on END's column.
        self.to_end: FloatArray = np.zeros((P, M), dtype=np.float64)
        self.to_end[np.arange(P), self.end_column] = 1.0
        self.silent = np.asarray([a.silent for a in actions], dtype=bool)
        self.silent_next: IntArray = np.asarray(silent_next, dtype=np.int64)
        self.silent_reward: FloatArray = np.asarray(
            [rewards.positive if a.kind is ActionKind.RESPOND else 0.0 for a in actions],
            dtype=np.float64,
        )
        self.is_query = np.asarray([a.kind in QUERY_KINDS for a in actions], dtype=bool)
        self.root_actions = (0, 1)
        self.INITIATE, self.PASS = self.root_actions
        # Contexts of an unavailable situation ("do not disturb"): the robot never initiates
        # there (app.learning.masks).
        quiet = set(mission.unavailable_situations)
        self.unavailable = np.asarray(
            [mission.context_names(c)[1] in quiet for c in range(self.n_contexts)], dtype=bool
        )
        self._succ_column = [{int(s): j for j, s in enumerate(row)} for row in succ]
        # actions_of is asked at every step of every decision: its ranges, built once.
        self._ranges = tuple(
            range(int(a), int(a) + int(n))
            for a, n in zip(self.state_start, self.state_count, strict=True)
        )
        self._detail_state = detail_state
        self._service_index = {s.name: k for k, s in enumerate(services)}
        self._action_index = {a: p for p, a in enumerate(actions)}
        for arr in (
            self.pair_state,
            self.state_start,
            self.state_count,
            self.succ,
            self.succ_mask,
            self.end_column,
            self.to_end,
            self.silent,
            self.silent_next,
            self.silent_reward,
            self.is_query,
            self.unavailable,
        ):
            arr.setflags(write=False)

    # -- lookups -------------------------------------------------------------------------------
    def actions_of(self, state: int) -> range:
        """The pair indices available in ``state`` (contiguous)."""
        return self._ranges[state]

    def successor_column(self, action: int, next_state: int) -> int:
        """Column of ``next_state`` in ``succ[action]``; ``ValueError`` if it cannot follow."""
        try:
            return self._succ_column[action][next_state]
        except KeyError:
            raise ValueError(
                f"{self.state_name(next_state)} cannot follow {self.action_name(action)}"
            ) from None

    def can_follow(self, action: int, next_state: int) -> bool:
        """Whether ``next_state`` can follow ``action`` (:meth:`successor_column` would answer)."""
        return next_state in self._succ_column[action]

    def request_state(self, service: str) -> int:
        return 1 + self._service_index[service]

    def type_known_state(self, service: str) -> int:
        return len(self.mission.services) + 2 + self._service_index[service]

    def detail_known_state(self, service: str, detail: str) -> int:
        k = self._service_index[service]
        return self._detail_state[(k, self.mission.services[k].details.index(detail))]

    def action_index(self, action: Action) -> int:
        return self._action_index[action]

    def state_info(self, state: int) -> StateInfo:
        return StateInfo(StateKind.END) if state == self.END else self.states[state]

    def state_name(self, state: int) -> str:
        info = self.state_info(state)
        parts = [p for p in (info.service, info.detail) if p]
        return f"{info.kind.value}({', '.join(parts)})" if parts else info.kind.value

    def action_name(self, action: int) -> str:
        a = self.actions[action]
        parts = [p for p in (a.service, a.detail) if p]
        return f"{a.kind.value}({', '.join(parts)})" if parts else a.kind.value

    def is_valid(self, state: int, action: int) -> bool:
        return 0 <= state < self.n_states and action in self.actions_of(state)


@functools.lru_cache(maxsize=16)
def space_for(mission: Mission) -> NegotiationSpace:
    """The (shared, read-only) space of a mission."""
    return NegotiationSpace(mission)
