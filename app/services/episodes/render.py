"""Stored rows as the v1 API's JSON (the shapes of ``app.schemas.episodes``), built as plain
dicts: the robots' writes answer with them and store them for idempotent replays."""

from __future__ import annotations

from typing import Any

from app.db.repositories.episodes import DecisionRow, EpisodeRow
from app.learning import NegotiationSpace
from app.learning.negotiation import EXPECTS

__all__ = ["action_out", "brief", "chain_out", "decision_out", "probabilities_out", "state_name"]


def state_name(space: NegotiationSpace, state: int) -> str:
    return space.state_info(state).kind.value


def action_out(space: NegotiationSpace, action: int) -> dict[str, str]:
    """``{"kind", "service"?, "detail"?}`` of a pair index."""
    return space.actions[action].to_dict()


def probabilities_out(
    space: NegotiationSpace, state: int, probs: list[float]
) -> list[dict[str, Any]]:
    actions = space.actions_of(state)
    return [{"action": action_out(space, a), "p": p} for a, p in zip(actions, probs, strict=True)]


def chain_out(space: NegotiationSpace, chain: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{"action": action_out(space, s["action"]), "p": s["p"]} for s in chain]


def decision_out(space: NegotiationSpace, row: DecisionRow) -> dict[str, Any]:
    kind = space.actions[row.action].kind
    return {
        "decision_id": row.id,
        "action": action_out(space, row.action),
        "expects": [r.value for r in EXPECTS[kind]],
        "probabilities": probabilities_out(space, row.state, row.probabilities),
        "chain": chain_out(space, row.chain),
    }


def brief(space: NegotiationSpace, ep: EpisodeRow) -> dict[str, Any]:
    return {
        "episode_id": ep.id,
        "status": ep.status,
        "state": state_name(space, ep.state),
        "total_reward": ep.total_reward,
    }
