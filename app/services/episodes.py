"""Episodes: an event starts a negotiation, outcomes move it on, feedback adds to it.

Every write locks the user first (``ensure_user``/``visible_user(for_update=True)``), then reads
what it needs, so the user's history and model change as one serial story whatever the number
of robots and workers. Each write hands the learner one batch (the outcome's transition and the
silent steps of the next decision), so the model's version goes up by exactly one per write.
"""

from __future__ import annotations

import datetime as dt
import secrets
from dataclasses import dataclass
from typing import Any

from sqlalchemy import Connection
from sqlalchemy.orm import Session

from app.db.models import Episode, Feedback, User
from app.db.repositories import episodes as repo
from app.db.repositories import negotiation as neg
from app.db.repositories.negotiation import DecisionRec, EpisodeRec, UserRec
from app.db.types import utcnow
from app.errors import Conflict, NotFound, ValidationFailed
from app.learning import Action, ActionKind, Observation, Polarity, Transition
from app.learning import Decision as Drawn
from app.learning.learners import TabularLearner
from app.schemas.common import ActionOut, ProbabilityOut, position_of
from app.schemas.episodes import (
    ContextOut,
    DecisionOut,
    EpisodeBrief,
    EpisodeCreated,
    EpisodeIn,
    EpisodeList,
    EpisodeSummary,
    EpisodeTrace,
    FeedbackIn,
    FeedbackOut,
    FeedbackTrace,
    OutcomeIn,
    OutcomeOut,
    TraceDecision,
)

from .context import Principal, ServiceContext, body_hash, rng_for
from .learners import learner_for_update, learner_for_write, save_feedback, store_update
from .users import ensure_user, visible_user

__all__ = ["EXPECTS", "add_feedback", "get_trace", "list_episodes", "report_outcome",
           "start_episode", "Written"]

EXPECTS: dict[ActionKind, tuple[str, ...]] = {
    ActionKind.INITIATE: ("accepted", "rejected", "terminated"),
    ActionKind.PASS: ("human_request", "none"),
    ActionKind.QUERY_TYPE: ("answered", "terminated"),
    ActionKind.QUERY_DETAIL: ("answered", "terminated"),
    ActionKind.PERFORM: ("accepted", "rejected", "terminated"),
}


@dataclass(frozen=True, slots=True)
class Written:
    """A write's response body, its status, and whether it replays an earlier write."""

    body: dict[str, Any]
    status: int
    replay: bool
    kind: str | None = None  # the answered action's kind (outcomes), for the metrics


# -- shared helpers ----------------------------------------------------------------------------
def _new_id(prefix: str) -> str:
    return prefix + secrets.token_hex(16)


def _state_name(ctx: ServiceContext, state: int) -> str:
    return ctx.space.state_info(state).kind.value


def _action_out(ctx: ServiceContext, action: int) -> ActionOut:
    a = ctx.space.actions[action]
    return ActionOut(kind=a.kind.value, service=a.service, detail=a.detail)


def _probabilities(ctx: ServiceContext, state: int, probs: list[float]) -> list[ProbabilityOut]:
    actions = ctx.space.actions_of(state)
    return [ProbabilityOut(action=_action_out(ctx, a), p=p) for a, p in zip(actions, probs,
                                                                             strict=True)]


def _chain_out(ctx: ServiceContext, chain: list[dict[str, Any]]) -> list[ProbabilityOut]:
    return [ProbabilityOut(action=_action_out(ctx, s["action"]), p=s["p"]) for s in chain]


def _decision_out(ctx: ServiceContext, row: DecisionRec) -> DecisionOut:
    kind = ctx.space.actions[row.action].kind
    return DecisionOut(
        decision_id=row.id, action=_action_out(ctx, row.action), expects=list(EXPECTS[kind]),
        probabilities=_probabilities(ctx, row.state, row.probabilities),
        chain=_chain_out(ctx, row.chain),
    )


def _brief(ctx: ServiceContext, ep: Episode | EpisodeRec) -> EpisodeBrief:
    return EpisodeBrief(episode_id=ep.id, status=ep.status,  # type: ignore[arg-type]
                        state=_state_name(ctx, ep.state), total_reward=ep.total_reward)


def _check_situation(ctx: ServiceContext, situation: str) -> None:
    if situation not in ctx.mission.situations:
        raise ValidationFailed(
            f"situation must be one of {', '.join(ctx.mission.situations)}; got {situation!r}."
        )


def _check_service(ctx: ServiceContext, service: str | None, detail: str | None, *,
                   need_service: bool, need_detail: bool) -> None:
    names = [s.name for s in ctx.mission.services]
    if service is None:
        if need_service:
            raise ValidationFailed(f"service is required here: one of {', '.join(names)}.")
        if detail is not None:
            raise ValidationFailed("detail needs a service.")
        return
    if service not in names:
        raise ValidationFailed(f"service must be one of {', '.join(names)}; got {service!r}.")
    details = ctx.mission.service(service).details
    if detail is None:
        if need_detail:
            raise ValidationFailed(f"detail is required here: one of {', '.join(details)}.")
    elif detail not in details:
        raise ValidationFailed(
            f"detail of {service} must be one of {', '.join(details)}; got {detail!r}."
        )


class _Step:
    """Draws decisions for one write and collects what it changes: the new decision rows and
    the transitions to teach the learner (the caller stores both)."""

    def __init__(self, ctx: ServiceContext, user: UserRec, episode: EpisodeRec,
                 learner: TabularLearner[Any], model_version: int, *, position: int) -> None:
        self.ctx, self.user, self.episode = ctx, user, episode
        self.learner, self.model_version = learner, model_version
        self.transitions: list[Transition] = []
        self.new_rows: list[DecisionRec] = []
        self._position = position  # of the next decision row in the episode

    def _draw(self, state: int) -> tuple[Drawn, int]:
        draw = self.user.draws
        rng = rng_for(self.ctx.settings.seed, self.user.user_id, draw)
        self.user.draws = draw + 1
        obs = Observation(self.episode.context, state, self.episode.learner_episode)
        return self.learner.select_action(obs, rng), draw

    def _row(self, drawn: Drawn, draw: int, chain: list[dict[str, Any]], *, forced: bool,
             action: int | None = None) -> DecisionRec:
        row = DecisionRec(
            id=_new_id("dec_"), episode_id=self.episode.id,
            position=self._next_position(), state=drawn.state,
            action=drawn.action if action is None else action,
            probabilities=[float(p) for p in drawn.probabilities], chain=chain, draw=draw,
            forced=forced, model_version=self.model_version, decided_at=utcnow(),
        )
        self.new_rows.append(row)
        return row

    def _next_position(self) -> int:
        pos = self._position
        self._position += 1
        return pos

    def teach(self, state: int, action: int, reward: float, next_state: int,
              signal: Polarity) -> None:
        self.transitions.append(Transition(self.episode.learner_episode, self.episode.context,
                                           state,
                                           action, float(reward), next_state, signal))

    def decide(self, state: int, *, forced_path: list[int] | None = None) -> DecisionRec:
        """The next visible decision from ``state``; ``forced_path`` are silent actions the
        person settled (a request's type and detail), taken before the learner chooses."""
        chain: list[dict[str, Any]] = []
        space = self.ctx.space
        for action in forced_path or []:
            nxt = int(space.silent_next[action])
            reward = float(space.silent_reward[action])
            chain.append({"state": state, "action": action, "p": 1.0, "next_state": nxt,
                          "reward": reward, "forced": True})
            self.teach(state, action, reward, nxt, Polarity.NEUTRAL)
            state = nxt
        drawn, draw = self._draw(state)
        for step in drawn.chain:
            p = float(step.probabilities[step.action - space.actions_of(step.state).start])
            chain.append({"state": step.state, "action": step.action, "p": p,
                          "next_state": step.next_state, "reward": step.reward})
            self.teach(step.state, step.action, step.reward, step.next_state, Polarity.NEUTRAL)
        self.episode.total_reward += sum(s["reward"] for s in chain)
        self.episode.state = drawn.state
        return self._row(drawn, draw, chain, forced=False)

    def human_root(self, service: str | None, detail: str | None) -> DecisionRec:
        """The root of a human-initiated episode: the robot was passive, the person asked."""
        space = self.ctx.space
        drawn, draw = self._draw(space.OBSERVE)
        row = self._row(drawn, draw, [], forced=True, action=space.PASS)
        nxt = space.request_state(service) if service is not None else space.ENGAGED
        self.answer(row, "human_request", service, detail, None, 0.0, nxt)
        self.teach(space.OBSERVE, space.PASS, 0.0, nxt, Polarity.POSITIVE)
        return row

    def answer(self, row: DecisionRec, response: str, service: str | None, detail: str | None,
                feedback: str | None, reward: float, next_state: int) -> None:
        row.response, row.service, row.detail, row.feedback = response, service, detail, feedback
        row.reward, row.next_state, row.answered_at = reward, next_state, utcnow()
        ep, space = self.episode, self.ctx.space
        ep.total_reward += reward
        ep.queries += int(space.is_query[row.action])
        if row.state == space.OBSERVE:
            ep.initiated = row.action == space.INITIATE
            ep.interaction_class = {
                "accepted": "I2", "rejected": "I3", "terminated": "I3",
                "human_request": "I1", "none": "none",
            }[response]
        if space.actions[row.action].kind is ActionKind.PERFORM and response == "accepted":
            ep.success = True
        ep.state = next_state
        if next_state == space.END:
            ep.status, ep.closed_at = "closed", utcnow()

    def after_request(self, state: int, service: str | None, detail: str | None
                      ) -> DecisionRec:
        """Continue after a person's request: respond, and infer the detail if they gave it."""
        space = self.ctx.space
        if service is None:
            return self.decide(space.ENGAGED)
        path = [space.actions_of(state).start]  # respond(k): REQUEST(k)'s only action
        if detail is not None:
            path.append(space.action_index(Action(ActionKind.INFER_DETAIL, service, detail)))
        return self.decide(state, forced_path=path)


# -- use cases ---------------------------------------------------------------------------------
def _locked_user(session: Session, conn: Connection, ctx: ServiceContext,
                 principal: Principal, user_id: str) -> UserRec:
    """Lock the user, creating it in the caller's fleet on its first event (404 for another
    fleet's user)."""
    user = neg.lock_user(conn, user_id)
    if user is None:  # once per user: the ORM path builds the fresh learner and its state
        ensure_user(session, ctx, principal, user_id)
        user = neg.lock_user(conn, user_id)
    if user is None or (not principal.is_admin and user.fleet != principal.fleet):
        raise NotFound(f"No user {user_id!r} in your fleet.")
    return user


def start_episode(
    session: Session, ctx: ServiceContext, principal: Principal, user_id: str, body: EpisodeIn
) -> Written:
    """An event near a user: open an episode and decide the robot's first action."""
    digest = body_hash(body)
    _check_situation(ctx, body.situation)
    if body.request is not None:
        if body.initiator != "human":
            raise ValidationFailed("request is only for initiator human (the person asked).")
        _check_service(ctx, body.request.service, body.request.detail, need_service=True,
                       need_detail=False)
    conn = session.connection()
    user = _locked_user(session, conn, ctx, principal, user_id)
    earlier = neg.episode_by_event(conn, user_id, body.event_id)
    if earlier is not None:
        request_hash, response = earlier
        if request_hash != digest:
            raise Conflict(f"event_id {body.event_id!r} was already used with another body.")
        return Written(response, 200, True)

    local = body.occurred_at.timetz().replace(tzinfo=None)
    slot = ctx.mission.slot_at(local)
    context = ctx.mission.context_index(slot, body.situation)
    model = neg.model_of(conn, user_id)
    if model is None:  # every user is created with its model; only a broken database lacks it
        raise RuntimeError(f"user {user_id!r} has no model row")
    learner = learner_for_write(conn, ctx, user_id, model.version)
    user.episode_count += 1
    episode = EpisodeRec(
        id=_new_id("ep_"), user_id=user_id, seq=user.episode_count,
        learner_episode=user.episode_count + model.episode_offset, event_id=body.event_id,
        robot_id=body.robot_id, occurred_at=body.occurred_at.astimezone(dt.UTC),
        time_slot=slot, situation=body.situation, context=context, initiator=body.initiator,
        request_service=body.request.service if body.request else None,
        request_detail=body.request.detail if body.request else None,
        status="open", state=ctx.space.OBSERVE, total_reward=0.0, interaction_class="none",
        initiated=False, success=False, queries=0, request_hash=digest, response={},
        created_at=utcnow(), closed_at=None,
    )
    step = _Step(ctx, user, episode, learner, model.version, position=0)
    if body.initiator == "human":
        service = body.request.service if body.request else None
        detail = body.request.detail if body.request else None
        root = step.human_root(service, detail)
        decision = step.after_request(int(root.next_state or 0), service, detail)
    else:
        decision = step.decide(ctx.space.OBSERVE)
    out = EpisodeCreated(
        episode_id=episode.id, user_id=user_id, status="open",
        context=ContextOut(time_slot=slot, situation=body.situation),
        state=_state_name(ctx, episode.state), total_reward=episode.total_reward,
        decision=_decision_out(ctx, decision),
    ).model_dump(mode="json")
    episode.response = out
    neg.insert_episode(conn, episode)  # before its decisions, which reference it
    neg.insert_decisions(conn, step.new_rows)
    neg.save_user_counters(conn, user)
    store_update(session, conn, ctx, user_id, model, learner, step.transitions)
    return Written(out, 201, False)


def _owned_episode(session: Session, principal: Principal, episode_id: str, *,
                   lock: bool) -> tuple[User, Episode]:
    owner = repo.episode_owner(session, episode_id)
    if owner is None or (not principal.is_admin and owner.fleet != principal.fleet):
        raise NotFound(f"No episode {episode_id!r} in your fleet.")
    user = visible_user(session, principal, owner.user_id, for_update=lock)
    episode = repo.get_episode(session, episode_id)
    if episode is None:  # deleted between the two reads
        raise NotFound(f"No episode {episode_id!r} in your fleet.")
    return user, episode


def _transition_of(ctx: ServiceContext, row: DecisionRec, body: OutcomeIn) -> tuple[float, int,
                                                                                 Polarity]:
    """(reward, next state, signal) of the person's response to a decision."""
    space, rw = ctx.space, ctx.mission.rewards
    action = space.actions[row.action]
    kind, END, r = action.kind, space.END, body.response
    query = rw.query if kind in (ActionKind.QUERY_TYPE, ActionKind.QUERY_DETAIL) else 0.0
    if r in ("rejected", "terminated"):
        return query + rw.negative, END, Polarity.NEGATIVE
    if kind is ActionKind.INITIATE:  # accepted
        return rw.positive, space.ENGAGED, Polarity.POSITIVE
    if kind is ActionKind.PASS:
        if r == "none":
            return 0.0, END, Polarity.NEUTRAL
        nxt = space.request_state(body.service) if body.service else space.ENGAGED
        return 0.0, nxt, Polarity.POSITIVE
    if kind is ActionKind.QUERY_TYPE:
        assert body.service is not None
        return query, space.type_known_state(body.service), Polarity.POSITIVE
    if kind is ActionKind.QUERY_DETAIL:
        assert action.service is not None
        assert body.detail is not None
        return query, space.detail_known_state(action.service, body.detail), Polarity.POSITIVE
    return rw.positive + rw.accepted_service, END, Polarity.POSITIVE  # perform accepted


def _check_outcome(ctx: ServiceContext, row: DecisionRec, body: OutcomeIn) -> None:
    action = ctx.space.actions[row.action]
    allowed = EXPECTS[action.kind]
    if body.response not in allowed:
        raise ValidationFailed(
            f"response to {action.kind.value} must be one of {', '.join(allowed)}; "
            f"got {body.response!r}."
        )
    if body.response == "human_request":
        _check_service(ctx, body.service, body.detail, need_service=False, need_detail=False)
    elif body.response == "answered" and action.kind is ActionKind.QUERY_TYPE:
        _check_service(ctx, body.service, body.detail, need_service=True, need_detail=False)
        if body.detail is not None:
            raise ValidationFailed("answer query_type with the service only; the detail is "
                                   "asked next.")
    elif body.response == "answered":  # query_detail
        if body.service is not None and body.service != action.service:
            raise ValidationFailed(f"this query_detail is about {action.service}; service must "
                                   f"be {action.service} or omitted.")
        _check_service(ctx, action.service, body.detail, need_service=True, need_detail=True)
    else:
        for name in ("service", "detail"):
            value = getattr(body, name)
            if value is not None and value != getattr(action, name):
                raise ValidationFailed(
                    f"{name} is only for answered or human_request responses (or must repeat "
                    f"the action's own {name})."
                )


def report_outcome(
    session: Session, ctx: ServiceContext, principal: Principal, episode_id: str, body: OutcomeIn
) -> Written:
    """What the person did after the robot's action: reward, learning, the next decision."""
    digest = body_hash(body)
    conn = session.connection()
    user = neg.lock_user_of_episode(conn, episode_id)
    loaded = neg.load_episode(conn, episode_id) if user is not None else None
    if user is None or loaded is None or (not principal.is_admin
                                          and user.fleet != principal.fleet):
        raise NotFound(f"No episode {episode_id!r} in your fleet.")
    episode, model, current = loaded
    row = current if current is not None and current.id == body.decision_id \
        else neg.decision_by_id(conn, episode_id, body.decision_id)
    if row is not None and row.outcome_hash is not None:
        if row.outcome_hash != digest:
            raise Conflict(f"Decision {body.decision_id!r} already has a different outcome.")
        return Written(row.outcome_response or {}, 200, True)
    if episode.status != "open":
        raise Conflict(f"Episode {episode_id!r} is closed; it takes no more outcomes.")
    if row is None or current is None or row.id != current.id:
        raise Conflict(
            f"Decision {body.decision_id!r} is not the current decision of episode "
            f"{episode_id!r}" + (f" ({current.id})." if current is not None else ".")
        )
    _check_outcome(ctx, row, body)
    reward, next_state, signal = _transition_of(ctx, row, body)
    rw = ctx.mission.rewards
    if body.feedback is not None:
        reward += rw.positive if body.feedback == "positive" else rw.negative
    learner = learner_for_write(conn, ctx, user.user_id, model.version)
    step = _Step(ctx, user, episode, learner, model.version, position=row.position + 1)
    service = body.service if body.response in ("human_request", "answered") else row.service
    detail = body.detail if body.response in ("human_request", "answered") else row.detail
    step.answer(row, body.response, service, detail, body.feedback, reward, next_state)
    step.teach(row.state, row.action, reward, next_state, signal)
    # The next decision is drawn before the learner is taught this outcome, so that the write
    # makes one ``update`` call (one version). In a context the negotiation is a DAG: learning
    # about the step just answered cannot change the values of the states after it.
    decision: DecisionRec | None = None
    if next_state != ctx.space.END:
        if body.response == "human_request":
            decision = step.after_request(next_state, body.service, body.detail)
        else:
            decision = step.decide(next_state)
    out = OutcomeOut(
        reward=reward, episode=_brief(ctx, episode),
        decision=_decision_out(ctx, decision) if decision is not None else None,
    ).model_dump(mode="json")
    row.outcome_hash, row.outcome_response = digest, out
    neg.save_answer(conn, row)
    neg.insert_decisions(conn, step.new_rows)
    neg.save_episode(conn, episode)
    if step.new_rows:
        neg.save_user_counters(conn, user)
    store_update(session, conn, ctx, user.user_id, model, learner, step.transitions)
    return Written(out, 200, False, ctx.space.actions[row.action].kind.value)


def add_feedback(
    session: Session, ctx: ServiceContext, principal: Principal, episode_id: str, body: FeedbackIn
) -> Written:
    """Explicit feedback on an episode, during or after it: it rewards the episode's last
    answered step, in history and in the model."""
    digest = body_hash(body)
    user, episode = _owned_episode(session, principal, episode_id, lock=True)
    earlier = repo.get_feedback(session, episode_id, body.feedback_id)
    if earlier is not None:
        if earlier.request_hash != digest:
            raise Conflict(f"feedback_id {body.feedback_id!r} was already used with another "
                           "body.")
        return Written(earlier.response, 200, True)
    answered = [d for d in repo.list_decisions(session, episode_id) if d.answered_at is not None]
    if not answered:
        raise Conflict(f"Episode {episode_id!r} has no answered step yet; give feedback with "
                       "the outcome (its feedback field) or after it.")
    target = answered[-1]
    rw = ctx.mission.rewards
    reward = rw.positive if body.feedback == "positive" else rw.negative
    model, learner = learner_for_update(session, ctx, user)
    save_feedback(session, ctx, user, model, learner, episode=episode.learner_episode,
                  context=episode.context, state=target.state, action=target.action,
                  reward=reward)
    episode.total_reward += reward
    out = FeedbackOut(reward=reward, episode=_brief(ctx, episode)).model_dump(mode="json")
    session.add(Feedback(episode_id=episode_id, feedback_id=body.feedback_id,
                         feedback=body.feedback, reward=reward, received_at=utcnow(),
                         request_hash=digest, response=out))
    session.flush()
    return Written(out, 200, False)


def _summary_fields(ctx: ServiceContext, ep: Episode) -> dict[str, Any]:
    return {
        "episode_id": ep.id, "user_id": ep.user_id, "event_id": ep.event_id,
        "robot_id": ep.robot_id, "status": ep.status,
        "context": ContextOut(time_slot=ep.time_slot, situation=ep.situation),
        "initiator": ep.initiator, "interaction_class": ep.interaction_class,
        "total_reward": ep.total_reward, "state": _state_name(ctx, ep.state),
        "occurred_at": ep.occurred_at, "index": ep.seq,
    }


def get_trace(session: Session, ctx: ServiceContext, principal: Principal, episode_id: str
              ) -> EpisodeTrace:
    _, ep = _owned_episode(session, principal, episode_id, lock=False)
    decisions = [
        TraceDecision(
            decision_id=d.id, state=_state_name(ctx, d.state), action=_action_out(ctx, d.action),
            probabilities=_probabilities(ctx, d.state, d.probabilities),
            chain=_chain_out(ctx, d.chain), response=d.response, service=d.service,
            detail=d.detail, feedback=d.feedback, reward=d.reward, decided_at=d.decided_at,
            answered_at=d.answered_at,
        )
        for d in repo.list_decisions(session, episode_id)
    ]
    feedback = [
        FeedbackTrace(feedback_id=f.feedback_id, feedback=f.feedback, reward=f.reward,
                      received_at=f.received_at)
        for f in repo.list_feedback(session, episode_id)
    ]
    return EpisodeTrace(**_summary_fields(ctx, ep), decisions=decisions, feedback=feedback)


def list_episodes(session: Session, ctx: ServiceContext, principal: Principal, user_id: str, *,
                  limit: int, cursor: str | None) -> EpisodeList:
    visible_user(session, principal, user_id)
    before: int | None = None
    if cursor is not None:
        before = position_of(cursor)
        if before is None:
            raise ValidationFailed("cursor is not one this API returned.")
    rows = repo.list_episodes(session, user_id, before_seq=before, limit=limit + 1)
    items = [EpisodeSummary(**_summary_fields(ctx, ep)) for ep in rows[:limit]]
    more = len(rows) > limit
    return EpisodeList(items=items, next_cursor=str(rows[limit - 1].seq) if more else None)


