"""What if another learner had served these people? Logging, replay and the truth, in simulation
(docs/method.md §17).

- :func:`log_person` runs a *logging* learner through a simulated person's events, exactly as
  :func:`app.learning.population.run_learner` does, and keeps what the service keeps of every
  decision: each step's state, action, reward and the whole distribution the action was drawn
  from (silent steps too).
- :func:`replay` feeds a *candidate* learner the logged history in order, as the service would
  have fed it online, and asks it at every logged step what it would have done there: its
  probability of the logged action, its mass on actions the logger never takes in that state,
  and its own model's values (for the doubly robust estimate). It learns from what was logged,
  not from what it would have caused: that is the approximation the validation measures.
- :func:`steps_of` flattens logs and replays into :class:`app.learning.offpolicy.Steps`.

The truth a what-if estimate is compared with is the candidate's own on-policy value on the same
persons, events and coin flips: :func:`app.learning.population.run_learner`.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .learners.base import TabularLearner
from .offpolicy import Steps
from .population import Person, run_learner, serve_event
from .types import Decision, FloatArray, Transition

__all__ = [
    "Decided",
    "PersonLog",
    "Replayed",
    "log_person",
    "replay",
    "replay_all",
    "replay_values",
    "steps_of",
]


@dataclass(frozen=True, slots=True)
class Decided:
    """One logged decision: the silent steps and the visible action of one ``select_action``,
    with the distribution each was drawn from (aligned with ``space.actions_of(state)``)."""

    event: int
    transitions: tuple[Transition, ...]
    distributions: tuple[FloatArray, ...]


@dataclass
class PersonLog:
    """A person's logged history: decisions in order, and each episode's total reward."""

    decisions: list[Decided] = field(default_factory=list)
    returns: list[float] = field(default_factory=list)

    @property
    def n_steps(self) -> int:
        return sum(len(d.transitions) for d in self.decisions)


@dataclass(frozen=True)
class Replayed:
    """A candidate's answers at every logged step of one person, in the log's order, shape
    (steps,) each: its probability of the logged action (``target``), of actions the logger
    gave probability 0 (``unsupported``), its model's value of the logged action
    (``q_hat``) and of the state under its own policy (``v_hat``)."""

    target: FloatArray
    unsupported: FloatArray
    q_hat: FloatArray
    v_hat: FloatArray


def log_person(
    learner: TabularLearner[Any], person: Person, uniforms: np.ndarray, rng: np.random.Generator
) -> PersonLog:
    """``learner`` through ``person``'s events, as :func:`app.learning.population.run_learner`
    runs it (the same rewards), keeping every decision."""
    log = PersonLog()

    def keep(event: int, decision: Decision, transitions: list[Transition]) -> None:
        dists = (*(c.probabilities for c in decision.chain), decision.probabilities)
        log.decisions.append(Decided(event, tuple(transitions), dists))

    log.returns = run_learner(learner, person, uniforms, rng, on_decision=keep).tolist()
    return log


def replay(log: PersonLog, candidate: TabularLearner[Any], rng: np.random.Generator) -> Replayed:
    """``candidate`` (fresh, or as the person's model stood before the log) through ``log``:
    before each logged decision it is asked what it would have done at each of its steps, then
    it learns the decision's transitions."""
    return replay_all(log, [candidate], [rng])[0]


def replay_all(
    log: PersonLog,
    candidates: Sequence[TabularLearner[Any]],
    rngs: Sequence[np.random.Generator],
) -> list[Replayed]:
    """:func:`replay` of each of ``candidates`` (each asked with its own ``rngs`` entry), the
    same answers, but fresh candidates that learn alike (the same algorithm, params differing
    only in how they decide: ``TabularLearner.learns_as``, e.g. HRI at several temperatures;
    nothing learned yet and no guidance) learn once: the first of them learns, and decides as
    each of the others in turn (``deciding_as``). The others are left as they were. A
    candidate that learned already, or carries guidance, is replayed on its own."""
    if len(candidates) != len(rngs):
        raise ValueError("one rng per candidate.")
    leaders: list[int] = []  # the candidate whose learner learns, for each candidate
    for i, c in enumerate(candidates):
        lead = next(
            (j for j, led in enumerate(leaders) if led == j and _fresh_alike(candidates[j], c)),
            i,
        )
        leaders.append(lead)
    learning = sorted(set(leaders))
    n = log.n_steps
    outs = [Replayed(np.empty(n), np.empty(n), np.empty(n), np.empty(n)) for _ in candidates]
    i = 0
    for d in log.decisions:
        first = d.transitions[0]
        states = [t.state for t in d.transitions]
        for k, c in enumerate(candidates):
            leader = candidates[leaders[k]]
            with leader.deciding_as(c.params) as deciding:
                space = deciding.space
                mine = deciding.distributions(first.context, states, first.episode, rngs[k])
                q = deciding.action_values(first.context, gamma=1.0)
            out = outs[k]
            for j, (t, theirs, ours) in enumerate(
                zip(d.transitions, d.distributions, mine, strict=True)
            ):
                actions = space.actions_of(t.state)
                out.target[i + j] = ours[t.action - actions.start]
                out.unsupported[i + j] = float(ours[theirs <= 0.0].sum())
                out.q_hat[i + j] = q[t.action]
                out.v_hat[i + j] = float(ours @ q[actions.start : actions.stop])
        i += len(d.transitions)
        for k in learning:
            candidates[k].update(list(d.transitions))
    return outs


def _fresh_alike(a: TabularLearner[Any], b: TabularLearner[Any]) -> bool:
    """Whether ``b`` may answer through ``a``'s tables: both fresh (nothing learned, no
    guidance), of one algorithm and learning alike."""
    return (
        type(a) is type(b)
        and a.version == b.version == 0
        and not a.guidance
        and not b.guidance
        and a.learns_as(b.params)
    )


def replay_values(
    log: PersonLog,
    candidate: TabularLearner[Any],
    person: Person,
    uniforms: np.ndarray,
    rng: np.random.Generator,
) -> FloatArray:
    """What the replay's approximation is worth, per event (shape (events,)): before each of
    ``person``'s logged events, a copy of ``candidate`` as the replay has taught it so far
    serves that event itself (learning within the episode, as online), and its reward is kept;
    then ``candidate`` learns the logged decisions of the event, as :func:`replay` teaches it.
    The mean is the value of "the candidate, learning from these logs", the quantity the
    off-policy estimates aim at; its distance from the candidate's own on-policy value is the
    approximation's (docs/method.md §17)."""
    by_event: dict[int, list[Decided]] = {}
    for d in log.decisions:
        by_event.setdefault(d.event, []).append(d)
    out = np.empty(person.n_events, dtype=np.float64)
    shared = {id(candidate.mission): candidate.mission, id(candidate.space): candidate.space}
    for e in range(person.n_events):
        out[e] = serve_event(copy.deepcopy(candidate, dict(shared)), person, uniforms, e, rng)
        for d in by_event.get(e, ()):
            candidate.update(list(d.transitions))
    return out


def logged_probabilities(log: PersonLog, space_actions: Any) -> FloatArray:
    """The logger's probability of each logged action, in the log's order."""
    out = [
        float(dist[t.action - space_actions(t.state).start])
        for d in log.decisions
        for t, dist in zip(d.transitions, d.distributions, strict=True)
    ]
    return np.asarray(out, dtype=np.float64)


def steps_of(
    logs: Sequence[PersonLog],
    replays: Sequence[Replayed],
    space_actions: Any,
    *,
    events: int | None = None,
) -> Steps:
    """The logged steps of every person (person i is cluster i), their episodes in order; with
    ``events``, only each person's first ``events`` episodes."""
    cluster: list[int] = []
    lengths: list[int] = []
    cols: dict[str, list[FloatArray]] = {k: [] for k in ("logged", "reward", *_REPLAYED)}
    for p, (log, rep) in enumerate(zip(logs, replays, strict=True)):
        step_event = np.asarray(
            [d.event for d in log.decisions for _ in d.transitions], dtype=np.int64
        )
        keep = step_event < (events if events is not None else np.iinfo(np.int64).max)
        kept = step_event[keep]
        if not len(kept):
            continue
        counts = np.bincount(kept)
        counts = counts[counts > 0]
        cluster += [p] * len(counts)
        lengths += counts.tolist()
        cols["logged"].append(logged_probabilities(log, space_actions)[keep])
        cols["reward"].append(
            np.asarray([t.reward for d in log.decisions for t in d.transitions], dtype=np.float64)[
                keep
            ]
        )
        for name in _REPLAYED:
            cols[name].append(getattr(rep, name)[keep])
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    return Steps(
        cluster=np.asarray(cluster, dtype=np.int64),
        offsets=offsets,
        **{k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()},
    )


_REPLAYED = ("target", "unsupported", "q_hat", "v_hat")
