"""A robot's request checked against the mission and the negotiation's rules, before anything
is read or written: 422 with a sentence that names what is wrong and what is allowed."""

from __future__ import annotations

from app.errors import ValidationFailed
from app.learning import ActionKind, Mission, NegotiationSpace
from app.learning.negotiation import EXPECTS
from app.schemas.episodes import EpisodeIn, OutcomeIn

__all__ = ["check_episode", "check_outcome", "check_service"]


def check_episode(mission: Mission, body: EpisodeIn) -> None:
    if body.situation not in mission.situations:
        raise ValidationFailed(
            f"situation must be one of {', '.join(mission.situations)}; got {body.situation!r}."
        )
    if body.request is not None:
        if body.initiator != "human":
            raise ValidationFailed("request is only for initiator human (the person asked).")
        check_service(
            mission, body.request.service, body.request.detail, need_service=True, need_detail=False
        )


def check_service(
    mission: Mission,
    service: str | None,
    detail: str | None,
    *,
    need_service: bool,
    need_detail: bool,
) -> None:
    names = [s.name for s in mission.services]
    if service is None:
        if need_service:
            raise ValidationFailed(f"service is required here: one of {', '.join(names)}.")
        if detail is not None:
            raise ValidationFailed("detail needs a service.")
        return
    if service not in names:
        raise ValidationFailed(f"service must be one of {', '.join(names)}; got {service!r}.")
    details = mission.service(service).details
    if detail is None:
        if need_detail:
            raise ValidationFailed(f"detail is required here: one of {', '.join(details)}.")
    elif detail not in details:
        raise ValidationFailed(
            f"detail of {service} must be one of {', '.join(details)}; got {detail!r}."
        )


def check_outcome(space: NegotiationSpace, action: int, body: OutcomeIn) -> None:
    """The response is one the decision's action allows, with the service or detail it needs
    (and none it does not)."""
    mission = space.mission
    act = space.actions[action]
    allowed = EXPECTS[act.kind]
    if body.response not in allowed:
        raise ValidationFailed(
            f"response to {act.kind.value} must be one of {', '.join(allowed)}; "
            f"got {body.response!r}."
        )
    if body.response == "human_request":
        check_service(mission, body.service, body.detail, need_service=False, need_detail=False)
    elif body.response == "answered" and act.kind is ActionKind.QUERY_TYPE:
        check_service(mission, body.service, body.detail, need_service=True, need_detail=False)
        if body.detail is not None:
            raise ValidationFailed(
                "answer query_type with the service only; the detail is asked next."
            )
    elif body.response == "answered":  # query_detail
        if body.service is not None and body.service != act.service:
            raise ValidationFailed(
                f"this query_detail is about {act.service}; service must "
                f"be {act.service} or omitted."
            )
        check_service(mission, act.service, body.detail, need_service=True, need_detail=True)
    else:
        for name in ("service", "detail"):
            value = getattr(body, name)
            if value is not None and value != getattr(act, name):
                raise ValidationFailed(
                    f"{name} is only for answered or human_request responses (or must repeat "
                    f"the action's own {name})."
                )
