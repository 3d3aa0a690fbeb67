"""OpenAPI links between operations: how a response's ids feed the next call (a user's id to
its episodes, an episode's decision to its outcome). Clients and stateful API testers follow
them; they add to the documented contract and change no behaviour."""

from __future__ import annotations

from typing import Any

__all__ = ["EPISODE_LINKS", "OUTCOME_LINKS", "USER_LINKS"]

_USER = {"user_id": "$response.body#/user_id"}

USER_LINKS: dict[str, Any] = {
    "GetUser": {
        "operationId": "get_user",
        "parameters": _USER,
        "description": "The user just created or updated.",
    },
    "StartEpisode": {
        "operationId": "start_episode",
        "parameters": _USER,
        "description": "An event near this user.",
    },
    "GetModel": {"operationId": "get_model", "parameters": _USER},
    "GetStats": {"operationId": "get_stats", "parameters": _USER},
    "ListEpisodes": {"operationId": "list_episodes", "parameters": _USER},
}

EPISODE_LINKS: dict[str, Any] = {
    "ReportOutcome": {
        "operationId": "report_outcome",
        "parameters": {"episode_id": "$response.body#/episode_id"},
        "requestBody": {"decision_id": "$response.body#/decision/decision_id"},
        "description": "What the person did after the first decision.",
    },
    "GetEpisode": {
        "operationId": "get_episode",
        "parameters": {"episode_id": "$response.body#/episode_id"},
    },
    "AddFeedback": {
        "operationId": "add_feedback",
        "parameters": {"episode_id": "$response.body#/episode_id"},
    },
}

OUTCOME_LINKS: dict[str, Any] = {
    "ReportNextOutcome": {
        "operationId": "report_outcome",
        "parameters": {"episode_id": "$request.path.episode_id"},
        "requestBody": {"decision_id": "$response.body#/decision/decision_id"},
        "description": "What the person did after the next decision (while there is one).",
    },
    "GetEpisode": {
        "operationId": "get_episode",
        "parameters": {"episode_id": "$request.path.episode_id"},
    },
}
