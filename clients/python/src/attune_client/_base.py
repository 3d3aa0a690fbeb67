"""What the sync and async clients share: configuration, the requests of every endpoint, and
reading the answers. Only sending (and sleeping) differs between them."""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import os
import random
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Generic, TypeVar
from urllib.parse import quote

import httpx
from pydantic import BaseModel

from ._exceptions import (
    APIConnectionError,
    APIStatusError,
    APITimeoutError,
    AttuneError,
    AuthenticationError,
    PermissionDeniedError,
)
from ._models import (
    ChangeList,
    Correction,
    CorrectionKind,
    CorrectionList,
    EpisodePage,
    EpisodeStarted,
    EpisodeTrace,
    Feedback,
    FeedbackResult,
    FleetMission,
    FleetPrior,
    FlushReport,
    Initiator,
    LearnerSpec,
    Mission,
    MissionChanged,
    MissionRenames,
    MissionVersionList,
    ModelView,
    OutcomeResponse,
    OutcomeResult,
    PendingReport,
    Profile,
    Rejection,
    ReportKind,
    ServiceRequest,
    Stats,
    User,
    UserPage,
)
from ._outbox import Outbox
from ._retry import Backoff
from ._version import __version__

__all__ = ["Api", "BaseClient", "Op", "ReportOp", "mission_change_id"]

T = TypeVar("T")
M = TypeVar("M", bound=BaseModel)
Delivered = tuple[PendingReport, OutcomeResult | FeedbackResult]
_KEEP_RESULTS = 1024  # results of automatic deliveries kept for the next flush()


@dataclass(frozen=True, slots=True)
class Op(Generic[T]):
    """One call of the API: the request, and how to read a successful answer."""

    method: str
    path: str
    parse: Callable[[httpx.Response], T]
    params: Mapping[str, str | int] | None = None
    body: bytes | None = None
    auth: bool = True


@dataclass(frozen=True, slots=True)
class ReportOp(Generic[T]):
    """An outcome or feedback report: a write the outbox may keep until it can be delivered."""

    kind: ReportKind
    episode_id: str
    key: str
    body: bytes
    parse: Callable[[httpx.Response], T]

    @property
    def path(self) -> str:
        return report_path(self.kind, self.episode_id)


# -- requests ----------------------------------------------------------------------------------
def _segment(value: str) -> str:
    """A path segment, percent-encoded (``.`` and ``..`` too, which URLs would collapse)."""
    if value in (".", ".."):
        return value.replace(".", "%2E")
    return quote(value, safe="")


def _json(body: Mapping[str, Any]) -> bytes:
    return json.dumps(body, separators=(",", ":"), ensure_ascii=False).encode()


def report_path(kind: ReportKind, episode_id: str) -> str:
    return f"/v1/episodes/{_segment(episode_id)}/{'outcomes' if kind == 'outcome' else kind}"


def _model(model: type[M]) -> Callable[[httpx.Response], M]:
    def parse(response: httpx.Response) -> M:
        return model.model_validate_json(response.content)

    return parse


def _written(model: type[M]) -> Callable[[httpx.Response], M]:
    """A write's answer, with ``replayed`` from the ``Idempotent-Replay`` header."""

    def parse(response: httpx.Response) -> M:
        data = response.json()
        if isinstance(data, dict):
            replay = response.headers.get("idempotent-replay", "").strip().lower() == "true"
            data = {**data, "replayed": replay}
        return model.model_validate(data)

    return parse


def _nothing(response: httpx.Response) -> None:
    return None


def _document(response: httpx.Response) -> dict[str, Any]:
    data = response.json()
    if not isinstance(data, dict):
        raise TypeError("the service answered an export with something else than an object")
    return data


def _timestamp(value: dt.datetime | str) -> str:
    if isinstance(value, dt.datetime):
        if value.tzinfo is None or value.utcoffset() is None:
            raise ValueError(
                "occurred_at needs a time zone (the local time of its offset picks "
                "the time slot); use an aware datetime"
            )
        return value.isoformat()
    return value


def _since(value: dt.datetime | str) -> str:
    if isinstance(value, dt.datetime):
        if value.tzinfo is None or value.utcoffset() is None:
            raise ValueError("since needs a time zone; use an aware datetime")
        return value.isoformat()
    return value


def _mission_document(mission: Mission | Mapping[str, Any]) -> dict[str, Any]:
    if isinstance(mission, Mission):
        return mission.document()
    if not isinstance(mission, Mapping):
        raise TypeError("mission must be a Mission or a mapping (the mission document)")
    return {k: v for k, v in mission.items() if k not in ("fleet", "version", "fingerprint")}


def _renames_document(renames: MissionRenames | Mapping[str, Any] | None) -> dict[str, Any] | None:
    if renames is None:
        return None
    spec = (
        renames
        if isinstance(renames, MissionRenames)
        else MissionRenames.model_validate(dict(renames))
    )
    doc = {k: v for k, v in spec.model_dump(mode="json").items() if v}
    return doc or None


def mission_change_id(
    mission: Mission | Mapping[str, Any], renames: MissionRenames | Mapping[str, Any] | None = None
) -> str:
    """The ``change_id`` ``set_mission`` uses when given none: ``mission-`` and a digest of the
    mission document (without ``fleet``, ``version`` and ``fingerprint``) and the renames, so
    that sending the same change again (a retry, a rerun of a script) is the same change."""
    doc = {"mission": _mission_document(mission), "renames": _renames_document(renames)}
    canonical = json.dumps(doc, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return "mission-" + hashlib.sha256(canonical.encode()).hexdigest()[:40]


def result_parser(kind: ReportKind) -> Callable[[httpx.Response], OutcomeResult | FeedbackResult]:
    if kind == "outcome":
        return _written(OutcomeResult)
    return _written(FeedbackResult)


class Api:
    """The requests of every endpoint (docs/api.md in the Attune repository)."""

    @staticmethod
    def health() -> Op[bool]:
        return Op("GET", "/healthz", lambda r: r.status_code == 200, auth=False)

    @staticmethod
    def ready() -> Op[bool]:
        return Op("GET", "/readyz", lambda r: r.status_code == 200, auth=False)

    @staticmethod
    def mission(fleet: str | None) -> Op[FleetMission]:
        return Op(
            "GET",
            "/v1/mission",
            _model(FleetMission),
            params={"fleet": fleet} if fleet is not None else None,
        )

    @staticmethod
    def missions(fleet: str) -> Op[MissionVersionList]:
        return Op("GET", f"/v1/admin/fleets/{_segment(fleet)}/missions", _model(MissionVersionList))

    @staticmethod
    def fleet_prior(fleet: str) -> Op[FleetPrior]:
        return Op("GET", f"/v1/admin/fleets/{_segment(fleet)}/prior", _model(FleetPrior))

    @staticmethod
    def set_fleet_prior(fleet: str, enabled: bool) -> Op[FleetPrior]:
        return Op(
            "PUT",
            f"/v1/admin/fleets/{_segment(fleet)}/prior",
            _model(FleetPrior),
            body=_json({"enabled": enabled}),
        )

    @staticmethod
    def set_mission(
        fleet: str,
        mission: Mission | Mapping[str, Any],
        change_id: str | None,
        renames: MissionRenames | Mapping[str, Any] | None,
    ) -> Op[MissionChanged]:
        body: dict[str, Any] = {
            "change_id": change_id
            if change_id is not None
            else mission_change_id(mission, renames),
            "mission": _mission_document(mission),
        }
        renamed = _renames_document(renames)
        if renamed is not None:
            body["renames"] = renamed
        return Op(
            "PUT",
            f"/v1/admin/fleets/{_segment(fleet)}/mission",
            _written(MissionChanged),
            body=_json(body),
        )

    @staticmethod
    def put_user(
        user_id: str,
        display_name: str | None,
        learner: LearnerSpec | Mapping[str, Any] | None,
        reset_model: bool,
        fleet_prior: bool | None = None,
    ) -> Op[User]:
        body: dict[str, Any] = {}
        if display_name is not None:
            body["display_name"] = display_name
        if fleet_prior is not None:
            body["fleet_prior"] = fleet_prior
        if learner is not None:
            spec = (
                learner
                if isinstance(learner, LearnerSpec)
                else LearnerSpec.model_validate(dict(learner))
            )
            body["learner"] = spec.model_dump(mode="json")
        params = {"reset_model": "true"} if reset_model else None
        return Op(
            "PUT", f"/v1/users/{_segment(user_id)}", _model(User), params=params, body=_json(body)
        )

    @staticmethod
    def get_user(user_id: str) -> Op[User]:
        return Op("GET", f"/v1/users/{_segment(user_id)}", _model(User))

    @staticmethod
    def list_users(limit: int, cursor: str | None) -> Op[UserPage]:
        params: dict[str, str | int] = {"limit": limit}
        if cursor is not None:
            params["cursor"] = cursor
        return Op("GET", "/v1/users", _model(UserPage), params=params)

    @staticmethod
    def delete_user(user_id: str) -> Op[None]:
        return Op("DELETE", f"/v1/users/{_segment(user_id)}", _nothing)

    @staticmethod
    def start_episode(
        user_id: str,
        *,
        event_id: str,
        occurred_at: dt.datetime | str,
        situation: str,
        initiator: Initiator,
        request: ServiceRequest | Mapping[str, Any] | None,
        robot_id: str | None,
    ) -> Op[EpisodeStarted]:
        asked: dict[str, Any] | None = None
        if request is not None:
            spec = (
                request
                if isinstance(request, ServiceRequest)
                else (ServiceRequest.model_validate(dict(request)))
            )
            asked = spec.model_dump(mode="json")
        body = {
            "event_id": event_id,
            "occurred_at": _timestamp(occurred_at),
            "situation": situation,
            "initiator": initiator,
            "request": asked,
            "robot_id": robot_id,
        }
        return Op(
            "POST",
            f"/v1/users/{_segment(user_id)}/episodes",
            _written(EpisodeStarted),
            body=_json(body),
        )

    @staticmethod
    def report_outcome(
        episode_id: str,
        *,
        decision_id: str,
        response: OutcomeResponse,
        service: str | None,
        detail: str | None,
        feedback: Feedback | None,
    ) -> ReportOp[OutcomeResult]:
        body: dict[str, Any] = {"decision_id": decision_id, "response": response}
        for name, value in (("service", service), ("detail", detail), ("feedback", feedback)):
            if value is not None:
                body[name] = value
        return ReportOp("outcome", episode_id, decision_id, _json(body), _written(OutcomeResult))

    @staticmethod
    def send_feedback(
        episode_id: str, *, feedback_id: str, feedback: Feedback
    ) -> ReportOp[FeedbackResult]:
        body = {"feedback_id": feedback_id, "feedback": feedback}
        return ReportOp("feedback", episode_id, feedback_id, _json(body), _written(FeedbackResult))

    @staticmethod
    def get_episode(episode_id: str) -> Op[EpisodeTrace]:
        return Op("GET", f"/v1/episodes/{_segment(episode_id)}", _model(EpisodeTrace))

    @staticmethod
    def list_episodes(user_id: str, limit: int, cursor: str | None) -> Op[EpisodePage]:
        params: dict[str, str | int] = {"limit": limit}
        if cursor is not None:
            params["cursor"] = cursor
        return Op(
            "GET", f"/v1/users/{_segment(user_id)}/episodes", _model(EpisodePage), params=params
        )

    @staticmethod
    def get_model(user_id: str, time_slot: str | None, situation: str | None) -> Op[ModelView]:
        params = {
            k: v for k, v in (("time_slot", time_slot), ("situation", situation)) if v is not None
        }
        return Op(
            "GET", f"/v1/users/{_segment(user_id)}/model", _model(ModelView), params=params or None
        )

    @staticmethod
    def get_stats(user_id: str, last: int | None) -> Op[Stats]:
        return Op(
            "GET",
            f"/v1/users/{_segment(user_id)}/stats",
            _model(Stats),
            params={"last": last} if last is not None else None,
        )

    @staticmethod
    def reset_model(user_id: str, drop_corrections: bool = False) -> Op[None]:
        return Op(
            "DELETE",
            f"/v1/users/{_segment(user_id)}/model",
            _nothing,
            params={"corrections": "drop"} if drop_corrections else None,
        )

    @staticmethod
    def get_profile(user_id: str) -> Op[Profile]:
        return Op("GET", f"/v1/users/{_segment(user_id)}/profile", _model(Profile))

    @staticmethod
    def list_corrections(user_id: str) -> Op[CorrectionList]:
        return Op("GET", f"/v1/users/{_segment(user_id)}/corrections", _model(CorrectionList))

    @staticmethod
    def add_correction(
        user_id: str,
        *,
        correction_id: str,
        time_slot: str,
        situation: str,
        kind: CorrectionKind,
        service: str | None,
        detail: str | None,
        note: str | None,
    ) -> Op[Correction]:
        body: dict[str, Any] = {
            "correction_id": correction_id,
            "time_slot": time_slot,
            "situation": situation,
            "kind": kind,
        }
        for name, value in (("service", service), ("detail", detail), ("note", note)):
            if value is not None:
                body[name] = value
        return Op(
            "POST",
            f"/v1/users/{_segment(user_id)}/corrections",
            _written(Correction),
            body=_json(body),
        )

    @staticmethod
    def lift_correction(user_id: str, correction_id: str) -> Op[None]:
        return Op(
            "DELETE",
            f"/v1/users/{_segment(user_id)}/corrections/{_segment(correction_id)}",
            _nothing,
        )

    @staticmethod
    def list_changes(user_id: str, limit: int, cursor: str | None) -> Op[ChangeList]:
        params: dict[str, str | int] = {"limit": limit}
        if cursor is not None:
            params["cursor"] = cursor
        return Op(
            "GET", f"/v1/users/{_segment(user_id)}/changes", _model(ChangeList), params=params
        )

    @staticmethod
    def list_fleet_changes(
        fleet: str, since: dt.datetime | str | None, limit: int, cursor: str | None
    ) -> Op[ChangeList]:
        params: dict[str, str | int] = {"limit": limit}
        if since is not None:
            params["since"] = _since(since)
        if cursor is not None:
            params["cursor"] = cursor
        return Op(
            "GET",
            f"/v1/admin/fleets/{_segment(fleet)}/changes",
            _model(ChangeList),
            params=params,
        )

    @staticmethod
    def export_model(user_id: str) -> Op[dict[str, Any]]:
        return Op("GET", f"/v1/users/{_segment(user_id)}/model/export", _document)

    @staticmethod
    def import_model(user_id: str, document: Mapping[str, Any]) -> Op[ModelView]:
        return Op(
            "PUT", f"/v1/users/{_segment(user_id)}/model", _model(ModelView), body=_json(document)
        )


# -- errors --------------------------------------------------------------------------------------
def transport_error(exc: httpx.TransportError, request: httpx.Request) -> APIConnectionError:
    if isinstance(exc, httpx.TimeoutException):
        return APITimeoutError(request=request)
    detail = str(exc) or type(exc).__name__
    return APIConnectionError(request=request, message=f"Connection error: {detail}")


def is_transient(exc: AttuneError) -> bool:
    """True when the report may get through later: no answer, a timeout, 408, 429 or 5xx."""
    if isinstance(exc, APIConnectionError):
        return True
    return isinstance(exc, APIStatusError) and (
        exc.status_code in (408, 429) or exc.status_code >= 500
    )


def refusal(exc: AttuneError) -> APIStatusError | None:
    """The error when the service refused the report itself for good (409, 404, 422, 413...),
    else None. An outcome of an episode interrupted by a mission change is one
    (``EpisodeInterruptedError``, a 409): no retry can deliver it. An unusable key (401, 403)
    is the caller's to fix, not the report's: a report refused for that stays queued."""
    if (
        isinstance(exc, APIStatusError)
        and 400 <= exc.status_code < 500
        and not is_transient(exc)
        and not isinstance(exc, AuthenticationError | PermissionDeniedError)
    ):
        return exc
    return None


def rejection(exc: APIStatusError) -> Rejection:
    return Rejection(
        status_code=exc.status_code,
        error=exc.error,
        detail=exc.detail,
        fields=exc.fields,
        request_id=exc.request_id,
        rejected_at=dt.datetime.now(dt.UTC),
    )


# -- shared state ------------------------------------------------------------------------------
class BaseClient:
    """Configuration and bookkeeping shared by ``Client`` and ``AsyncClient``."""

    def __init__(
        self,
        base_url: str,
        api_key: str,
        *,
        max_retries: int,
        outbox: str | os.PathLike[str] | None,
        headers: Mapping[str, str] | None,
    ) -> None:
        if max_retries < 0:
            raise ValueError("max_retries must be 0 or more")
        self.base_url = base_url
        self.max_retries = max_retries
        self._api_key = api_key
        self._extra_headers = dict(headers or {})
        self._outbox = Outbox(outbox) if outbox is not None else None
        self._backoff = Backoff()
        self._random: Callable[[], float] = random.random
        self._delivered: deque[Delivered] = deque(maxlen=_KEEP_RESULTS)
        self._rejected: deque[tuple[PendingReport, Rejection]] = deque(maxlen=_KEEP_RESULTS)

    def _headers(self) -> dict[str, str]:
        return {
            "User-Agent": f"attune-client/{__version__} python-httpx/{httpx.__version__}",
            "Accept": "application/json",
            **self._extra_headers,
        }

    def _build(
        self, http: httpx.Client | httpx.AsyncClient, op: Op[Any] | ReportOp[Any]
    ) -> httpx.Request:
        headers: dict[str, str] = {}
        body: bytes | None
        if isinstance(op, ReportOp):
            method, params, body, auth = "POST", None, op.body, True
        else:
            method, params, body, auth = op.method, op.params, op.body, op.auth
        if auth and self._api_key:
            headers["Authorization"] = f"Bearer {self._api_key}"
        if body is not None:
            headers["Content-Type"] = "application/json"
        return http.build_request(method, op.path, params=params, content=body, headers=headers)

    def _entry_op(
        self, entry: PendingReport, body: bytes
    ) -> ReportOp[OutcomeResult | FeedbackResult]:
        return ReportOp(entry.kind, entry.episode_id, entry.key, body, result_parser(entry.kind))

    def _take_report(self) -> FlushReport:
        delivered, rejected = list(self._delivered), list(self._rejected)
        self._delivered.clear()
        self._rejected.clear()
        remaining = self._outbox.count() if self._outbox is not None else 0
        return FlushReport(delivered=delivered, rejected=rejected, remaining=remaining)
