"""The package's public surface: what ``import attune_client`` gives, and nothing of the
service."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import attune_client


def test_all_imports_are_exported() -> None:
    included_private_members = ["__title__", "__version__"]
    assert attune_client.__all__ == sorted(
        (
            member
            for member in vars(attune_client)
            if not member.startswith("_") or member in included_private_members
        ),
        key=str.casefold,
    )


def test_the_public_api_is_there() -> None:
    expected = {
        "Client",
        "AsyncClient",
        "DEFAULT_TIMEOUT",
        "DEFAULT_MAX_RETRIES",
        "AttuneError",
        "APIConnectionError",
        "APITimeoutError",
        "APIStatusError",
        "BadRequestError",
        "AuthenticationError",
        "PermissionDeniedError",
        "NotFoundError",
        "ConflictError",
        "PayloadTooLargeError",
        "UnprocessableEntityError",
        "RateLimitError",
        "InternalServerError",
        "ServiceUnavailableError",
        "OutboxError",
        "Action",
        "ActionKind",
        "OutcomeResponse",
        "Feedback",
        "Initiator",
        "NegotiationState",
        "CorrectionKind",
        "Outcome",
        "ActionProbability",
        "Decision",
        "Context",
        "EpisodeStarted",
        "EpisodeState",
        "OutcomeResult",
        "FeedbackResult",
        "User",
        "UserPage",
        "EpisodeTrace",
        "EpisodeSummary",
        "EpisodePage",
        "ModelView",
        "Stats",
        "Mission",
        "LearnerSpec",
        "ServiceRequest",
        "Queued",
        "PendingReport",
        "FlushReport",
        "FleetMission",
        "MissionVersion",
        "MissionVersionList",
        "MissionChanged",
        "MissionRenames",
        "EpisodeInterruptedError",
        "mission_change_id",
        "Profile",
        "ProfileContext",
        "ProfileEvidence",
        "ProfileChange",
        "RobotWill",
        "Wanted",
        "Correction",
        "CorrectionList",
        "ChangeEvent",
        "ChangeEvidence",
        "ChangeList",
        "ChangeMoment",
        "ChangeSource",
    }
    assert expected <= set(attune_client.__all__)
    methods = {
        "health",
        "ready",
        "mission",
        "put_user",
        "get_user",
        "list_users",
        "iter_users",
        "delete_user",
        "start_episode",
        "report_outcome",
        "send_feedback",
        "get_episode",
        "list_episodes",
        "iter_episodes",
        "get_model",
        "get_stats",
        "reset_model",
        "export_model",
        "import_model",
        "flush",
        "pending",
        "missions",
        "set_mission",
        "get_profile",
        "list_corrections",
        "add_correction",
        "lift_correction",
        "list_changes",
        "iter_changes",
        "list_fleet_changes",
        "iter_fleet_changes",
    }
    for cls in (attune_client.Client, attune_client.AsyncClient):
        missing = {m for m in methods if not callable(getattr(cls, m, None))}
        assert not missing, (cls.__name__, missing)
        undocumented = {m for m in methods if not getattr(cls, m).__doc__}
        assert not undocumented, (cls.__name__, undocumented)


def test_the_errors_form_one_hierarchy() -> None:
    a = attune_client
    assert issubclass(a.APITimeoutError, a.APIConnectionError)
    assert issubclass(a.APIConnectionError, a.AttuneError)
    assert issubclass(a.ServiceUnavailableError, a.InternalServerError)
    assert issubclass(a.OutboxError, a.AttuneError)
    assert issubclass(a.EpisodeInterruptedError, a.ConflictError)
    assert not issubclass(a.OutboxError, a.APIStatusError | a.APIConnectionError)
    for cls in (
        a.BadRequestError,
        a.AuthenticationError,
        a.PermissionDeniedError,
        a.NotFoundError,
        a.ConflictError,
        a.PayloadTooLargeError,
        a.UnprocessableEntityError,
        a.RateLimitError,
        a.InternalServerError,
    ):
        assert issubclass(cls, a.APIStatusError)
        assert issubclass(cls, a.AttuneError)


def test_the_package_is_typed() -> None:
    assert (Path(attune_client.__file__).parent / "py.typed").is_file()


def test_it_imports_nothing_of_the_service() -> None:
    code = (
        "import sys, attune_client; "
        "bad = sorted(m for m in sys.modules if m == 'app' or m.startswith('app.')); "
        "print(bad); sys.exit(1 if bad else 0)"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 0, done.stdout + done.stderr
