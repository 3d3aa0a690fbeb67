"""The robots' writes: start an episode, report an outcome, give feedback.

Each reads as: lock the user, load what it needs, ask the learning core for the step, store.
The lock comes first (``users.lock`` / ``users.lock_owner``), so a user's history and model
change as one serial story whatever the number of robots and workers; each write hands the
learner one batch (an outcome's transition and the silent steps of the next decision, or one
feedback), so the model's version goes up by exactly one per write.
"""

from __future__ import annotations

import datetime as dt
import secrets
from dataclasses import dataclass
from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import batch
from app.db.repositories import episodes as episodes_repo
from app.db.repositories import users as users_repo
from app.db.repositories.episodes import DecisionRow, EpisodeRow, FeedbackRow
from app.db.repositories.models import ModelRow
from app.db.repositories.users import UserRow
from app.db.session import NOWAIT, LockBusy
from app.db.types import utcnow
from app.errors import Conflict, NotFound
from app.learning import (
    Action,
    ActionKind,
    Decision,
    Interaction,
    NegotiationSpace,
    Observation,
    Polarity,
    Transition,
)
from app.learning.negotiation import Tally, feedback_reward, outcome
from app.schemas.episodes import EpisodeIn, FeedbackIn, OutcomeIn

from .. import changes, missions
from ..context import Principal, ServiceContext, body_hash, rng_for
from ..person_model import PersonModel
from ..users import create_user, fleet_of, no_user
from . import validate
from .render import brief, decision_out, state_name

__all__ = ["Written", "add_feedback", "report_outcome", "start_episode"]


@dataclass(frozen=True, slots=True)
class Written:
    """A write's response body, its status, and whether it replays an earlier write."""

    body: dict[str, Any]
    status: int
    replay: bool
    kind: str | None = None  # the answered action's kind (outcomes), for the metrics
    fleet: str | None = None  # the user's fleet, for the metrics


def _new_id(prefix: str) -> str:
    return prefix + secrets.token_hex(16)


def _offset_minutes(at: dt.datetime) -> int | None:
    offset = at.utcoffset()
    return None if offset is None else int(offset.total_seconds() // 60)


def _not_found_episode(episode_id: str) -> NotFound:
    return NotFound(f"No episode {episode_id!r} in your fleet.")


class _Negotiation:
    """One write's steps through an episode: the decisions it draws, the steps it executes and
    the episode's figures; the caller stores the new decision rows and teaches the learner the
    transitions, in one batch."""

    def __init__(
        self,
        ctx: ServiceContext,
        space: NegotiationSpace,
        user: UserRow,
        episode: EpisodeRow,
        model: PersonModel,
        *,
        position: int,
    ) -> None:
        self.ctx, self.space = ctx, space
        self.user, self.episode = user, episode
        self.model, self.model_version = model, model.version
        self.transitions: list[Transition] = []
        self.new_rows: list[DecisionRow] = []
        self._position = position  # of the next decision row in the episode
        self.tally = Tally(
            initiated=episode.initiated,
            interaction=Interaction(episode.interaction_class),
            success=episode.success,
            queries=episode.queries,
            reward=episode.total_reward,
        )

    def _draw(self, state: int) -> tuple[Decision, int]:
        draw = self.user.draws
        rng = rng_for(self.ctx.settings.seed, self.user.seed_key, draw)
        self.user.draws = draw + 1
        obs = Observation(self.episode.context, state, self.episode.learner_episode)
        return self.model.learner.select_action(obs, rng), draw

    def _row(
        self,
        drawn: Decision,
        draw: int,
        chain: list[dict[str, Any]],
        *,
        forced: bool,
        action: int | None = None,
    ) -> DecisionRow:
        row = DecisionRow(
            id=_new_id("dec_"),
            episode_id=self.episode.id,
            position=self._position,
            state=drawn.state,
            action=drawn.action if action is None else action,
            probabilities=[float(p) for p in drawn.probabilities],
            chain=chain,
            draw=draw,
            forced=forced,
            model_version=self.model_version,
            decided_at=utcnow(),
        )
        self._position += 1
        self.new_rows.append(row)
        return row

    def execute(
        self,
        state: int,
        action: int,
        reward: float,
        next_state: int,
        signal: Polarity = Polarity.NEUTRAL,
    ) -> None:
        """A step was taken: count it in the episode's figures and teach it."""
        self.tally.step(self.space, state, action, reward, next_state, signal)
        self.transitions.append(
            Transition(
                self.episode.learner_episode,
                self.episode.context,
                state,
                action,
                float(reward),
                next_state,
                signal,
            )
        )

    def decide(self, state: int, *, forced_path: tuple[int, ...] = ()) -> DecisionRow:
        """The next visible decision from ``state``; ``forced_path`` are silent actions the
        person settled (a request's type and detail), taken before the learner chooses."""
        chain: list[dict[str, Any]] = []
        space = self.space
        for action in forced_path:
            nxt = int(space.silent_next[action])
            reward = float(space.silent_reward[action])
            chain.append(
                {
                    "state": state,
                    "action": action,
                    "p": 1.0,
                    "next_state": nxt,
                    "reward": reward,
                    "forced": True,
                }
            )
            self.execute(state, action, reward, nxt)
            state = nxt
        drawn, draw = self._draw(state)
        for step in drawn.chain:
            p = float(step.probabilities[step.action - space.actions_of(step.state).start])
            chain.append(
                {
                    "state": step.state,
                    "action": step.action,
                    "p": p,
                    "next_state": step.next_state,
                    "reward": step.reward,
                }
            )
            self.execute(step.state, step.action, step.reward, step.next_state)
        self.episode.state = drawn.state
        return self._row(drawn, draw, chain, forced=False)

    def answer(
        self,
        row: DecisionRow,
        *,
        response: str,
        service: str | None,
        detail: str | None,
        feedback: str | None,
    ) -> float:
        """The person's response to ``row``: the step's reward (explicit feedback included),
        stored on the row, counted and taught; the episode moves to the next state."""
        space = self.space
        step = outcome(space, row.action, response, service=service, detail=detail)
        reward = step.reward
        if feedback is not None:
            reward += feedback_reward(space.mission.rewards, feedback)
        row.response, row.service, row.detail, row.feedback = response, service, detail, feedback
        row.reward, row.next_state, row.answered_at = reward, step.next_state, utcnow()
        self.execute(row.state, row.action, reward, step.next_state, step.signal)
        self.episode.state = step.next_state
        if step.next_state == space.END:
            self.episode.status, self.episode.closed_at = "closed", utcnow()
        return reward

    def human_root(self, service: str | None, detail: str | None) -> DecisionRow:
        """The root of a human-initiated episode: the robot was passive, the person asked."""
        space = self.space
        drawn, draw = self._draw(space.OBSERVE)
        row = self._row(drawn, draw, [], forced=True, action=space.PASS)
        self.answer(row, response="human_request", service=service, detail=detail, feedback=None)
        return row

    def after_request(self, state: int, service: str | None, detail: str | None) -> DecisionRow:
        """Continue after a person's request: respond, and infer the detail if they gave it."""
        space = self.space
        if service is None:
            return self.decide(space.ENGAGED)
        path = [space.actions_of(state).start]  # respond(k): REQUEST(k)'s only action
        if detail is not None:
            path.append(space.action_index(Action(ActionKind.INFER_DETAIL, service, detail)))
        return self.decide(state, forced_path=tuple(path))

    def finish(self) -> None:
        """Write the figures back on the episode."""
        ep, t = self.episode, self.tally
        ep.total_reward, ep.queries, ep.success = t.reward, t.queries, t.success
        ep.initiated, ep.interaction_class = t.initiated, t.interaction.value


def _store(session: Session, step: _Negotiation) -> None:
    """The write's new decisions and the user's counters, and the model's change (journal,
    version, snapshot when due). Writes only: the model was taught before (it may have had to
    read its learner), so that on PostgreSQL they all go in one round trip."""
    episodes_repo.insert_decisions(session, step.new_rows)
    users_repo.save_counters(session, step.user)
    step.model.save()


def _lock_or_create(
    session: Session, ctx: ServiceContext, principal: Principal, user_id: str, fleet: str | None
) -> UserRow:
    """Lock the user of the caller's fleet (an admin's: of ``fleet``), creating it on its
    first event."""
    in_fleet = fleet_of(principal, fleet, user_id)
    user = users_repo.lock(session, in_fleet, user_id)
    if user is None and session.info.get(NOWAIT):
        raise LockBusy  # a new user is made where it may wait (for the fleet's mission lock)
    if user is None:  # once per user: build the fresh learner and its state
        create_user(session, ctx, in_fleet, user_id)
        user = users_repo.lock(session, in_fleet, user_id)
    if user is None:
        raise no_user(user_id)
    return user


def _locked_owner(
    session: Session, principal: Principal, episode_id: str
) -> tuple[UserRow, EpisodeRow, ModelRow, DecisionRow | None]:
    """Lock the user of an episode and load the episode, its user's model head and its current
    decision; another fleet's episode is answered as one that does not exist."""
    user = users_repo.lock_owner(session, episode_id)
    loaded = episodes_repo.load_for_outcome(session, episode_id) if user is not None else None
    if user is None or loaded is None or not principal.sees(user.fleet):
        raise _not_found_episode(episode_id)
    return (user, *loaded)


def _carried(
    session: Session,
    ctx: ServiceContext,
    fleet: str,
    episode: EpisodeRow,
    target: DecisionRow,
    layout: int,
) -> tuple[int, int, int] | None:
    """(context, state, action) of an answered step in the model's layout (the episode may be
    of an older mission version); ``None`` if the step no longer exists."""
    context, state, action = episode.context, target.state, target.action
    for step in missions.space_map(session, ctx, fleet, episode.mission_version, layout):
        c, s, a = step.context(context), step.state(state), step.action(action)
        if c is None or s is None or a is None:
            return None
        context, state, action = c, s, a
    return context, state, action


def start_episode(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    body: EpisodeIn,
    *,
    fleet: str | None = None,
) -> Written:
    """An event near a user: open an episode and decide the robot's first action."""
    digest = body_hash(body)
    user = _lock_or_create(session, ctx, principal, user_id, fleet)
    earlier = episodes_repo.by_event(session, user.id, body.event_id)
    if earlier is not None:
        request_hash, response = earlier
        if request_hash != digest:
            raise Conflict(f"event_id {body.event_id!r} was already used with another body.")
        return Written(response, 200, True, fleet=user.fleet)

    model = PersonModel.open(session, ctx, user, write=True)
    layout = ctx.missions.get(session, user.fleet, model.mission_version)
    mission, space = layout.mission, layout.space
    validate.check_episode(mission, body)
    slot = mission.slot_at(body.occurred_at.timetz().replace(tzinfo=None))
    context = mission.context_index(slot, body.situation)
    user.episode_count += 1
    request = body.request
    episode = EpisodeRow(
        id=_new_id("ep_"),
        user_pk=user.id,
        seq=user.episode_count,
        learner_episode=user.episode_count + model.head.episode_offset,
        event_id=body.event_id,
        robot_id=body.robot_id,
        occurred_at=body.occurred_at.astimezone(dt.UTC),
        time_slot=slot,
        situation=body.situation,
        context=context,
        initiator=body.initiator,
        request_service=request.service if request else None,
        request_detail=request.detail if request else None,
        status="open",
        state=space.OBSERVE,
        total_reward=0.0,
        interaction_class=Interaction.NONE.value,
        initiated=False,
        success=False,
        queries=0,
        request_hash=digest,
        response={},
        created_at=utcnow(),
        closed_at=None,
        mission_version=model.mission_version,
        utc_offset=_offset_minutes(body.occurred_at),
    )
    step = _Negotiation(ctx, space, user, episode, model, position=0)
    if body.initiator == "human":
        service = request.service if request else None
        detail = request.detail if request else None
        root = step.human_root(service, detail)
        decision = step.after_request(int(root.next_state or 0), service, detail)
    else:
        decision = step.decide(space.OBSERVE)
    step.finish()
    out = {
        "episode_id": episode.id,
        "user_id": user_id,
        "status": "open",
        "context": {"time_slot": slot, "situation": body.situation},
        "state": state_name(space, episode.state),
        "total_reward": episode.total_reward,
        "decision": decision_out(space, decision),
        "mission_version": model.mission_version,
    }
    episode.response = out
    model.teach(step.transitions)
    noticed = changes.notice(session, user, model, space, ended=None)  # news for staff
    with batch(session):  # writes only: one round trip on PostgreSQL
        episodes_repo.insert_episode(session, episode)  # before its decisions, which refer to it
        _store(session, step)
        if noticed is not None:
            noticed.store(session)
    return Written(out, 201, False, fleet=user.fleet)


def report_outcome(
    session: Session, ctx: ServiceContext, principal: Principal, episode_id: str, body: OutcomeIn
) -> Written:
    """What the person did after the robot's action: reward, learning, the next decision."""
    digest = body_hash(body)
    user, episode, head, current = _locked_owner(session, principal, episode_id)
    row = (
        current
        if current is not None and current.id == body.decision_id
        else episodes_repo.decision(session, episode_id, body.decision_id)
    )
    if row is not None and row.outcome_hash is not None:
        if row.outcome_hash != digest:
            raise Conflict(f"Decision {body.decision_id!r} already has a different outcome.")
        return Written(row.outcome_response or {}, 200, True)
    if episode.status == "interrupted":
        raise Conflict(
            f"Episode {episode_id!r} was interrupted when its fleet's mission "
            "changed; it takes no more outcomes. Start a new episode."
        )
    if episode.status != "open":
        raise Conflict(f"Episode {episode_id!r} is closed; it takes no more outcomes.")
    if row is None or current is None or row.id != current.id:
        raise Conflict(
            f"Decision {body.decision_id!r} is not the current decision of episode "
            f"{episode_id!r}" + (f" ({current.id})." if current is not None else ".")
        )
    # An open episode is always of the model's mission version: a change interrupts them.
    space = ctx.missions.get(session, user.fleet, episode.mission_version).space
    validate.check_outcome(space, row.action, body)
    model = PersonModel.open(session, ctx, user, write=True, head=head)
    step = _Negotiation(ctx, space, user, episode, model, position=row.position + 1)
    named = body.response in ("human_request", "answered")
    reward = step.answer(
        row,
        response=body.response,
        service=body.service if named else row.service,
        detail=body.detail if named else row.detail,
        feedback=body.feedback,
    )
    # The next decision is drawn before the learner is taught this outcome, so that the write
    # makes one ``update`` call (one version). In a context the negotiation is a DAG: learning
    # about the step just answered cannot change the values of the states after it.
    decision: DecisionRow | None = None
    next_state = episode.state
    if next_state != space.END:
        if body.response == "human_request":
            decision = step.after_request(next_state, body.service, body.detail)
        else:
            decision = step.decide(next_state)
    step.finish()
    out = {
        "reward": reward,
        "episode": brief(space, episode),
        "decision": decision_out(space, decision) if decision is not None else None,
    }
    row.outcome_hash, row.outcome_response = digest, out
    model.teach(step.transitions)
    ended = None
    if episode.status == "closed" and not model.learner.decides_changes:
        earlier = [d for d in episodes_repo.decisions(session, episode_id) if d.id != row.id]
        ended = (episode, [*earlier, row])
    noticed = changes.notice(session, user, model, space, ended=ended)  # news for staff
    with batch(session):  # writes only: one round trip on PostgreSQL
        episodes_repo.save_answer(session, row)
        episodes_repo.save_episode(session, episode)
        _store(session, step)
        if noticed is not None:
            noticed.store(session)
    return Written(out, 200, False, space.actions[row.action].kind.value, user.fleet)


def add_feedback(
    session: Session, ctx: ServiceContext, principal: Principal, episode_id: str, body: FeedbackIn
) -> Written:
    """Explicit feedback on an episode, during or after it: it rewards the episode's last
    answered step, in history and (if the model still holds that step) in the model."""
    digest = body_hash(body)
    user, episode, head, _ = _locked_owner(session, principal, episode_id)
    earlier = episodes_repo.feedback(session, episode_id, body.feedback_id)
    if earlier is not None:
        if earlier.request_hash != digest:
            raise Conflict(f"feedback_id {body.feedback_id!r} was already used with another body.")
        return Written(earlier.response, 200, True)
    answered = [
        d for d in episodes_repo.decisions(session, episode_id) if d.answered_at is not None
    ]
    if not answered:
        raise Conflict(
            f"Episode {episode_id!r} has no answered step yet; give feedback with "
            "the outcome (its feedback field) or after it."
        )
    target = answered[-1]
    model = PersonModel.open(session, ctx, user, write=True, head=head)
    reward = feedback_reward(model.mission.rewards, body.feedback)
    # The model takes it if it learned the step (not if it was reset or replaced since) and,
    # after a mission change, if the step still exists (carried to the model's layout).
    place = _carried(session, ctx, user.fleet, episode, target, model.mission_version)
    if place is not None and model.holds_step(
        episode=episode.learner_episode, action=target.action
    ):
        context, state, action = place
        # A learner that no longer holds the step refuses it: history keeps the feedback.
        model.feedback(
            episode=episode.learner_episode,
            context=context,
            state=state,
            action=action,
            reward=reward,
        )
        model.save()
    episode.total_reward += reward
    space = ctx.missions.get(session, user.fleet, episode.mission_version).space
    out = {"reward": reward, "episode": brief(space, episode)}
    episodes_repo.save_episode(session, episode)
    episodes_repo.add_feedback(
        session,
        FeedbackRow(
            episode_id=episode_id,
            feedback_id=body.feedback_id,
            feedback=body.feedback,
            reward=reward,
            received_at=utcnow(),
            request_hash=digest,
            response=out,
        ),
    )
    return Written(out, 200, False)
