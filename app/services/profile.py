"""A person's profile: what Attune believes they want in each context, how sure it is, what the
robot will do there, and why, in plain words (docs/method.md §14).

Built from the person's history (their own answers, :mod:`app.learning.beliefs`) and the model
(what the robot will do is the learner's action distribution as ``GET /model`` reports it, with
the staff corrections applied).
"""

from __future__ import annotations

import re
from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import retention as folds_repo
from app.learning import ActionKind, Mission, NegotiationSpace
from app.learning.beliefs import Item
from app.learning.guidance import Rule, RuleKind
from app.learning.learners import TabularLearner
from app.learning.masks import initiates_never
from app.schemas.models import StartedFrom
from app.schemas.profile import (
    ChangeOut,
    EvidenceOut,
    ProfileContext,
    ProfileOut,
    RobotWill,
    RolloutArmOut,
    Wanted,
)

from . import rollouts
from .context import Principal, ServiceContext
from .corrections import correction_views
from .folds import ContextHistory, History, Moment
from .person_model import PersonModel
from .prior import started_from
from .users import visible_user

__all__ = ["profile_view", "thing", "when_where", "words"]


def profile_view(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    *,
    fleet: str | None = None,
) -> ProfileOut:
    """The profile of ``user_id`` (robots, staff of the fleet, admins)."""
    user = visible_user(session, principal, user_id, fleet=fleet)
    model = PersonModel.open(session, ctx, user)
    learner = model.learner
    mission = learner.mission
    display = ctx.missions.display(session, user.fleet, model.mission_version)
    spaces: dict[int, NegotiationSpace] = {}

    def space_of(version: int) -> NegotiationSpace:
        if version not in spaces:
            spaces[version] = ctx.missions.get(session, user.fleet, version).space
        return spaces[version]

    history = History.from_doc(folds_repo.doc(session, user.id))
    history.walk_stored(
        session,
        user.id,
        space_of,
        upto_seq=user.episode_count,
        keep_moments={r.overridden_at for r in learner.guidance.rules if r.overridden_at},
    )
    corrections = correction_views(session, user, learner, lifted=False)
    now = model.now
    contexts = []
    for c in range(mission.n_contexts):
        slot, situation = mission.context_names(c)
        here = history.context(slot, situation)
        rules = [
            r for r in learner.guidance.rules if (r.time_slot, r.situation) == (slot, situation)
        ]
        contexts.append(
            _context(
                learner,
                c,
                now,
                slot,
                situation,
                here,
                rules,
                history.moments,
                user.display_name or user.user_id,
                display,
            )
        )
    arm = rollouts.person_arm(session, user.id)
    return ProfileOut(
        user_id=user.user_id,
        display_name=user.display_name,
        episodes=history.episodes,
        open_episodes=history.open,
        utc_offset=history.utc_offset,
        started_from=StartedFrom(**started_from(session, user.id)),
        contexts=contexts,
        corrections=corrections,
        rollout=None if arm is None else RolloutArmOut.model_validate(arm),
    )


def _context(
    learner: TabularLearner[Any],
    c: int,
    now: int,
    slot: str,
    situation: str,
    here: ContextHistory,
    rules: list[Rule],
    moments: dict[int, Moment],
    name: str | None,
    display: Mission,
) -> ProfileContext:
    found = here.fold.belief()
    wants, certainty, source = found.wants, found.certainty, "person" if found.wants else None
    change = None
    if found.change is not None:
        change = ChangeOut(
            at=here.times.get(found.change.seq),
            episode=found.change.seq,
            before=_wanted(found.change.before),
            now=_wanted(found.change.now),
        )
    prefers = [r for r in rules if r.kind is RuleKind.PREFERS]
    standing = [r for r in prefers if r.in_force and _fits(learner, r)]
    if standing:
        rule = standing[-1]
        assert rule.service is not None
        wants, certainty, source = Item(rule.service, rule.detail), "confident", "staff"
    else:
        overridden = [r for r in prefers if r.overridden_at is not None]
        if overridden:
            rule = overridden[-1]
            assert rule.service is not None
            moment = moments.get(rule.overridden_at or 0)
            change = ChangeOut(
                at=None if moment is None else moment.at,
                episode=0 if moment is None else moment.seq,
                before=Wanted(service=rule.service, detail=rule.detail),
                now=_wanted(found.wants),
                overrides=rule.id,
            )
    turned_down = found.wants is None and any(e.refused_offer for e in here.recent(3))
    will = _robot_will(learner, c, now, rules, turned_down)
    ev = EvidenceOut(
        accepted=here.accepted,
        refused=here.refused,
        asked_for=here.asked_for,
        answered=here.answered,
        last_seen=here.last_seen,
        support=found.support if source == "person" else 0,
        recent=found.recent,
    )
    summary = _summary(display, name, slot, situation, wants, certainty, source, will, ev, change)
    return ProfileContext(
        time_slot=slot,
        situation=situation,
        episodes=here.episodes,
        open_episodes=here.open,
        wants=_wanted(wants),
        certainty=certainty,  # type: ignore[arg-type]
        source=source,  # type: ignore[arg-type]
        evidence=ev,
        robot_will=will,
        summary=summary,
        changed=change,
        corrections=[r.id for r in rules],
    )


def _fits(learner: TabularLearner[Any], rule: Rule) -> bool:
    try:
        rule.check(learner.mission)
    except ValueError:
        return False
    return True


def _wanted(item: Item | None) -> Wanted | None:
    return None if item is None else Wanted(service=item.service, detail=item.detail)


def _robot_will(
    learner: TabularLearner[Any], c: int, now: int, rules: list[Rule], turned_down: bool
) -> RobotWill:
    """The most likely course of the robot's next decision here, from the learner's action
    distribution (``explain``, corrections applied)."""
    space = learner.space
    p = learner.explain(c, now).probabilities
    offer = float(p[space.INITIATE])
    if offer < 0.5:
        quiet = initiates_never(space, learner.guidance, c)
        return RobotWill(
            action="stay_away" if quiet or turned_down else "wait_to_be_asked",
            service=None,
            detail=None,
            asks_first=False,
            probability=offer,
        )
    service = detail = None
    asks = False
    engaged = space.actions_of(space.ENGAGED)
    best = engaged.start + int(p[engaged.start : engaged.stop].argmax())
    act = space.actions[best]
    if act.kind is ActionKind.QUERY_TYPE:
        asks = True
    else:
        service = act.service
        assert service is not None
        typed = space.actions_of(space.type_known_state(service))
        pick = space.actions[typed.start + int(p[typed.start : typed.stop].argmax())]
        if pick.kind is ActionKind.QUERY_DETAIL:
            asks = True
        else:
            detail = pick.detail
    return RobotWill(
        action="offer", service=service, detail=detail, asks_first=asks, probability=offer
    )


_AT = {"noon": "At noon", "midday": "At midday", "night": "At night", "midnight": "At midnight"}
_IN_THE = {"morning", "afternoon", "evening"}
_SITUATION_WORDS = {
    "arriving": "on arrival",
    "working": "while working",
    "stretching": "while stretching",
    "busy": "while busy",
}


def words(name: str | None) -> str:
    """A mission name in words: ``ProvideDrink`` -> "provide drink", ``today_agenda`` ->
    "today agenda"."""
    if not name:
        return ""
    spaced = re.sub(r"(?<=[a-z0-9])(?=[A-Z])", " ", name).replace("_", " ")
    return spaced.lower()


def _labelled(mission: Mission, name: str) -> str | None:
    return dict(mission.labels).get(name)


def _word(mission: Mission, name: str | None) -> str:
    """A name as the sentence says it: its label, else the name in words."""
    if not name:
        return ""
    return _labelled(mission, name) or words(name)


def thing(mission: Mission, item: Item | Wanted) -> str:
    """A service, or its detail when known, as a sentence says it ("tea")."""
    return _thing(mission, item)


def when_where(mission: Mission, slot: str, situation: str) -> str:
    """A context as the middle of a sentence says it ("in the afternoon, while stretching")."""
    when = _when(mission, slot)
    return f"{when[:1].lower()}{when[1:]}, {_where(mission, situation)}"


def _thing(mission: Mission, item: Item | Wanted) -> str:
    return _word(mission, item.detail) if item.detail else _word(mission, item.service)


def _when(mission: Mission, slot: str) -> str:
    label = _labelled(mission, slot)
    if label is not None:
        return label[:1].upper() + label[1:]
    if slot in _AT:
        return _AT[slot]
    if slot in _IN_THE:
        return f"In the {slot}"
    return mission.label(slot)


def _where(mission: Mission, situation: str) -> str:
    label = _labelled(mission, situation)
    if label is not None:
        return label
    return _SITUATION_WORDS.get(situation) or words(situation)


def _summary(
    mission: Mission,
    name: str | None,
    slot: str,
    situation: str,
    wants: Item | None,
    certainty: str,
    source: str | None,
    will: RobotWill,
    ev: EvidenceOut,
    change: ChangeOut | None,
) -> str:
    """The context's sentence, from the mission's labels (the office mission's names read as
    before: "In the afternoon, while stretching, ...")."""
    who = name or "this person"
    where = f"{_when(mission, slot)}, {_where(mission, situation)}"
    if will.action == "offer":
        if will.service is None:
            does = "the robot offers help and asks what is wanted"
        elif will.asks_first:
            does = f"the robot offers {_word(mission, will.service)} and asks which first"
        else:
            thing = _thing(mission, Item(will.service, will.detail))
            does = f"the robot offers {thing} without asking"
    elif will.action == "stay_away":
        does = "the robot does not approach on its own"
    else:
        does = "the robot waits to be asked"
    if wants is None:
        said = f"{where}, there is not enough to say yet what {who} wants"
        if change is not None and change.before is not None:
            said = f"{where}, {who} no longer seems to want {_thing(mission, change.before)}"
        return f"{said}; {does}."
    if source == "staff":
        return (
            f"{where}, staff say {who} wants {_thing(mission, wants)}; {does} (staff correction)."
        )
    usual = "usually wants" if certainty == "confident" else "may want"
    basis = f"{certainty}: {ev.support} of the last {ev.recent} answers agree"
    if change is not None and change.before is not None:
        basis += f"; changed from {_thing(mission, change.before)}"
    return f"{where}, {who} {usual} {_thing(mission, wants)}; {does} ({basis})."
