"""``Client`` and ``AsyncClient``: the v1 API as typed methods, with bounded retries and an
optional offline outbox for outcome and feedback reports."""

from __future__ import annotations

import datetime as dt
import functools
import os
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator, Mapping
from types import TracebackType
from typing import Any, Self, TypeVar

import anyio
import anyio.to_thread
import httpx

from ._base import (
    Api,
    BaseClient,
    Op,
    ReportOp,
    is_transient,
    refusal,
    rejection,
    transport_error,
)
from ._constants import DEFAULT_MAX_RETRIES, DEFAULT_TIMEOUT
from ._exceptions import AttuneError, make_status_error
from ._models import (
    ChangeEvent,
    ChangeList,
    Correction,
    CorrectionKind,
    CorrectionList,
    EpisodePage,
    EpisodeStarted,
    EpisodeSummary,
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
    Queued,
    Rejection,
    ServiceRequest,
    Stats,
    User,
    UserPage,
)
from ._retry import should_retry_status

__all__ = ["AsyncClient", "Client"]

T = TypeVar("T")


class Client(BaseClient):
    """A synchronous client of the Attune v1 API. Use it as a context manager, or call
    ``close()``. It is safe to share between threads.

    Args:
        base_url: where the service runs, e.g. ``"https://attune.example.org"``.
        api_key: a key made with ``attune keys create`` (sent as ``Authorization: Bearer``).
        timeout: seconds (or an ``httpx.Timeout``) per attempt; ``DEFAULT_TIMEOUT`` allows
            3 s to connect and 10 s for the rest.
        max_retries: retries after a failed first attempt (``DEFAULT_MAX_RETRIES`` = 3).
            Connection errors, timeouts, 408, 429, 500, 502, 503 and 504 are retried, after
            0.5 s doubling up to 8 s (less up to a quarter, at random), or after the
            ``Retry-After`` the service asked for; other errors are raised at once.
        outbox: a local SQLite file for outcome and feedback reports the service cannot take
            now (no connection, timeout, 408, 429, 5xx after the retries). Such reports are
            kept there and return ``Queued`` instead of raising; they are delivered, in order
            and exactly once, before the next call or by ``flush()``, also by a later process
            that opens the same file. Without it, those failures raise.
        transport: an httpx transport (``httpx.MockTransport`` in tests, ``ASGITransport``
            in-process).
        headers: extra headers sent with every request.
    """

    def __init__(
        self,
        base_url: str,
        api_key: str,
        *,
        timeout: float | httpx.Timeout = DEFAULT_TIMEOUT,
        max_retries: int = DEFAULT_MAX_RETRIES,
        outbox: str | os.PathLike[str] | None = None,
        transport: httpx.BaseTransport | None = None,
        headers: Mapping[str, str] | None = None,
    ) -> None:
        super().__init__(base_url, api_key, max_retries=max_retries, outbox=outbox, headers=headers)
        self._http = httpx.Client(
            base_url=base_url, timeout=timeout, transport=transport, headers=self._headers()
        )
        self._lock = threading.RLock()
        self._sleep: Callable[[float], None] = time.sleep

    @property
    def timeout(self) -> httpx.Timeout:
        """The timeout of every attempt."""
        return self._http.timeout

    def close(self) -> None:
        """Close the connections and the outbox file (queued reports stay in it)."""
        self._http.close()
        if self._outbox is not None:
            self._outbox.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- sending -------------------------------------------------------------------------------
    def _send(self, request: httpx.Request, *, max_retries: int) -> httpx.Response:
        attempt = 0
        while True:
            try:
                response = self._http.send(request)
            except httpx.TransportError as exc:
                if attempt >= max_retries:
                    raise transport_error(exc, request) from exc
                delay = self._backoff.delay(attempt, None, self._random)
            else:
                if response.is_success:
                    return response
                if attempt >= max_retries or not should_retry_status(response.status_code):
                    raise make_status_error(response)
                delay = self._backoff.delay(attempt, response, self._random)
            self._sleep(delay)
            attempt += 1

    def _call(self, op: Op[T], *, retries: int | None = None) -> T:
        # Deliver the queue first, unless another thread is busy with it (or with a report).
        if self._outbox is not None and self._outbox.count() and self._lock.acquire(blocking=False):
            try:
                self._deliver(max_retries=0, wait=False, strict=False)
            finally:
                self._lock.release()
        request = self._build(self._http, op)
        response = self._send(request, max_retries=self.max_retries if retries is None else retries)
        return op.parse(response)

    def _report(self, op: ReportOp[T]) -> T | Queued:
        request = self._build(self._http, op)
        outbox = self._outbox
        if outbox is None:
            return op.parse(self._send(request, max_retries=self.max_retries))
        with self._lock:
            if outbox.count():
                self._deliver(max_retries=0, wait=False, strict=False)
            if outbox.count():  # keep the order: behind the reports still waiting
                return outbox.append(op.kind, op.episode_id, op.key, op.body)
            try:
                response = self._send(request, max_retries=self.max_retries)
            except AttuneError as exc:
                if not is_transient(exc):
                    raise
                return outbox.append(
                    op.kind,
                    op.episode_id,
                    op.key,
                    op.body,
                    attempts=self.max_retries + 1,
                    last_error=str(exc),
                )
        return op.parse(response)

    def _deliver(self, *, max_retries: int, wait: bool, strict: bool) -> None:
        """Send the queue, head first, until it is empty or a report cannot get through.
        Called with ``self._lock`` held."""
        outbox = self._outbox
        assert outbox is not None
        while True:
            if not outbox.begin(wait=wait):
                return  # another process is delivering; it keeps the order
            try:
                head = outbox.head()
                if head is None:
                    outbox.commit()
                    return
                entry, body = head
                op = self._entry_op(entry, body)
                try:
                    response = self._send(self._build(self._http, op), max_retries=max_retries)
                except AttuneError as exc:
                    refused = refusal(exc)
                    if refused is not None:
                        why = rejection(refused)
                        outbox.reject(entry, why)
                        outbox.commit()
                        self._rejected.append((entry, why))
                        continue
                    tries = max_retries + 1 if is_transient(exc) else 1
                    outbox.note_failure(entry.seq, str(exc), tries)
                    outbox.commit()
                    if strict and not is_transient(exc):
                        raise
                    return
                outbox.remove(entry.seq)
                outbox.commit()
            except BaseException:
                outbox.rollback()
                raise
            self._delivered.append((entry, op.parse(response)))

    # -- the outbox ----------------------------------------------------------------------------
    def flush(self) -> FlushReport:
        """Deliver the outbox now, oldest report first, with the usual retries.

        Stops at the first report that still cannot get through (it stays at the head, so the
        order holds). A report the service refuses for good (404, 409, 413, 422...) leaves the
        queue for the outbox's rejected table and is never sent again. An outcome of an episode
        that a change of its fleet's mission interrupted is one of those (409,
        ``Rejection.interrupted``, listed in the report's ``interrupted``): the episode is over,
        and the person's next event starts a new one. Waits if another process is delivering
        the same file.

        Returns:
            What was delivered (with the service's answers: an outcome's answer holds the next
            decision of its episode) and rejected since the previous ``flush()``, including the
            reports delivered automatically before other calls, and how many remain.

        Raises:
            AuthenticationError, PermissionDeniedError: the key cannot deliver anything; the
                reports stay queued for a client with a usable key.
        """
        if self._outbox is not None:
            with self._lock:
                self._deliver(max_retries=self.max_retries, wait=True, strict=True)
        with self._lock:
            return self._take_report()

    def pending(self) -> list[PendingReport]:
        """The reports waiting in the outbox, oldest first (empty without an outbox).

        Each names its episode and ``key`` (the ``decision_id`` of an outcome, the
        ``feedback_id`` of feedback): while an outcome is pending, its episode cannot go on.
        """
        return self._outbox.entries() if self._outbox is not None else []

    def rejected(self) -> list[tuple[PendingReport, Rejection]]:
        """The outbox's reports that the service refused for good, oldest first, with the
        reasons (they are kept in the outbox file, out of the queue)."""
        return self._outbox.rejected() if self._outbox is not None else []

    # -- service -------------------------------------------------------------------------------
    def health(self) -> bool:
        """``GET /healthz``: True while the service process runs; False when it does not
        answer (one attempt, no retries). Needs no key."""
        try:
            return self._call(Api.health(), retries=0)
        except AttuneError:
            return False

    def ready(self) -> bool:
        """``GET /readyz``: True when the service and its database are ready; False when it
        answers 503 or does not answer (one attempt, no retries). Needs no key."""
        try:
            return self._call(Api.ready(), retries=0)
        except AttuneError:
            return False

    def mission(self, fleet: str | None = None) -> FleetMission:
        """``GET /v1/mission``: your fleet's mission in force (situations, time slots,
        services, rewards), with ``fleet``, ``version`` and ``fingerprint``.

        ``mission.document()`` is the mission alone (what ``set_mission`` takes).

        Args:
            fleet: another fleet's mission (admin keys only); None: the key's fleet.

        Raises:
            PermissionDeniedError: ``fleet`` named by a key that is not an admin's.
        """
        return self._call(Api.mission(fleet))

    def missions(self, fleet: str) -> MissionVersionList:
        """``GET /v1/admin/fleets/{fleet}/missions``: every version of a fleet's mission,
        newest first (the fleet's staff, admins).

        Raises:
            PermissionDeniedError: a robot key, or staff of another fleet.
        """
        return self._call(Api.missions(fleet))

    def fleet_prior(self, fleet: str) -> FleetPrior:
        """``GET /v1/admin/fleets/{fleet}/prior``: the fleet's prior for newcomers (the fleet's
        staff, admins).

        Raises:
            PermissionDeniedError: a robot key, or staff of another fleet.
        """
        return self._call(Api.fleet_prior(fleet))

    def set_fleet_prior(self, fleet: str, *, enabled: bool) -> FleetPrior:
        """``PUT /v1/admin/fleets/{fleet}/prior``: turn the fleet's prior on or off for its
        next newcomers (the fleet's staff, admins); models already started keep their start.

        Raises:
            PermissionDeniedError: a robot key, or staff of another fleet.
        """
        return self._call(Api.set_fleet_prior(fleet, enabled))

    def set_mission(
        self,
        fleet: str,
        mission: Mission | Mapping[str, Any],
        *,
        change_id: str | None = None,
        renames: MissionRenames | Mapping[str, Any] | None = None,
    ) -> MissionChanged:
        """``PUT /v1/admin/fleets/{fleet}/mission``: give a fleet a new mission (the fleet's
        staff, admins).

        Every model of the fleet is carried to the new version by names (what exists in both
        keeps what was learned) and the fleet's open episodes are closed as ``interrupted``
        (their pending outcomes get ``EpisodeInterruptedError``). A mission equal to the one
        in force changes nothing (``changed`` False).

        Args:
            fleet: whose mission.
            mission: a ``Mission`` (``fleet``, ``version`` and ``fingerprint`` are left out)
                or the mission document as a mapping (a mission file's JSON).
            change_id: makes the change idempotent (``^[A-Za-z0-9._:-]{1,128}$``). None:
                ``mission_change_id(mission, renames)``, derived from the content, so that a
                retry or a rerun is the same change (answered with ``replayed`` True). To go
                back to a mission the fleet had before, pass a new ``change_id``: the derived
                one would replay the earlier change instead.
            renames: old names to new (``MissionRenames`` or a mapping of ``time_slots``,
                ``situations``, ``services``, ``details``) for what was learned to follow.

        Raises:
            UnprocessableEntityError: the mission or the renames are not valid (``detail``
                says where).
            ConflictError: ``change_id`` was used with another mission.
            PermissionDeniedError: a robot key, or staff of another fleet.
        """
        return self._call(Api.set_mission(fleet, mission, change_id, renames))

    # -- users ---------------------------------------------------------------------------------
    def put_user(
        self,
        user_id: str,
        *,
        display_name: str | None = None,
        learner: LearnerSpec | Mapping[str, Any] | None = None,
        reset_model: bool = False,
        fleet_prior: bool | None = None,
    ) -> User:
        """``PUT /v1/users/{user_id}``: create or update a user (idempotent).

        Args:
            user_id: the fleet's id of the person (``^[A-Za-z0-9._:-]{1,128}$``).
            display_name: a name for people; unchanged when None.
            learner: the learning algorithm and its parameters; unchanged when None (a new
                user gets ``hri`` with tau 0.01).
            reset_model: allow changing the learner of a user who has history (what was
                learned is forgotten); without it that change is a ``ConflictError``.
            fleet_prior: whether the person takes part in the fleet's prior (a new user starts
                from it; the user's model adds to it); unchanged when None (a new user: True).

        Raises:
            UnprocessableEntityError: an unknown algorithm or bad parameters.
            ConflictError: a new learner for a user with history, without ``reset_model``.
        """
        return self._call(Api.put_user(user_id, display_name, learner, reset_model, fleet_prior))

    def get_user(self, user_id: str) -> User:
        """``GET /v1/users/{user_id}``.

        Raises:
            NotFoundError: no such user in your fleet.
        """
        return self._call(Api.get_user(user_id))

    def list_users(self, *, limit: int = 50, cursor: str | None = None) -> UserPage:
        """``GET /v1/users``: one page of users (your fleet's; an admin's sees all), by id.
        Pass the page's ``next_cursor`` as ``cursor`` for the next."""
        return self._call(Api.list_users(limit, cursor))

    def iter_users(self, *, page_size: int = 100) -> Iterator[User]:
        """Every user, page after page of ``page_size``."""
        cursor: str | None = None
        while True:
            page = self.list_users(limit=page_size, cursor=cursor)
            yield from page.items
            if page.next_cursor is None:
                return
            cursor = page.next_cursor

    def delete_user(self, user_id: str) -> None:
        """``DELETE /v1/users/{user_id}`` (admin): remove a user with history and model.

        Raises:
            PermissionDeniedError: not an admin key.
            NotFoundError: no such user.
        """
        self._call(Api.delete_user(user_id))

    # -- episodes ------------------------------------------------------------------------------
    def start_episode(
        self,
        user_id: str,
        *,
        event_id: str,
        occurred_at: dt.datetime | str,
        situation: str,
        initiator: Initiator = "robot",
        request: ServiceRequest | Mapping[str, Any] | None = None,
        robot_id: str | None = None,
    ) -> EpisodeStarted:
        """``POST /v1/users/{user_id}/episodes``: an event happened near this person; open an
        episode and get the robot's first decision.

        Repeating an ``event_id`` with the same arguments returns the same episode with
        ``replayed=True``. The user is created on first use. This call is never queued: a robot
        that cannot reach the service gets ``APIConnectionError`` and falls back to its own
        default behaviour.

        Args:
            user_id: the person.
            event_id: the robot's unique id of the event (``^[A-Za-z0-9._:-]{1,128}$``).
            occurred_at: when, with a time zone (an aware ``datetime`` or RFC 3339 text); the
                local time of its offset picks the time slot.
            situation: one of the mission's situations (``arriving``, ``working``...).
            initiator: ``"robot"`` (the robot noticed the person) or ``"human"`` (the person
                addressed the robot first).
            request: with ``initiator="human"``, what the person asked for.
            robot_id: which robot saw the event.

        Raises:
            UnprocessableEntityError: an unknown situation, a bad id or time.
            ConflictError: the ``event_id`` was used with other arguments.
            ValueError: ``occurred_at`` is a naive ``datetime``.
        """
        return self._call(
            Api.start_episode(
                user_id,
                event_id=event_id,
                occurred_at=occurred_at,
                situation=situation,
                initiator=initiator,
                request=request,
                robot_id=robot_id,
            )
        )

    def report_outcome(
        self,
        episode_id: str,
        *,
        decision_id: str,
        response: OutcomeResponse,
        service: str | None = None,
        detail: str | None = None,
        feedback: Feedback | None = None,
    ) -> OutcomeResult | Queued:
        """``POST /v1/episodes/{episode_id}/outcomes``: what the person did after the robot's
        action; returns its reward and the next decision (None when the episode ended).

        With an outbox, an outcome the service cannot take now is queued and ``Queued`` is
        returned; so is every outcome while older reports wait (the order holds).

        Args:
            episode_id: the episode.
            decision_id: the decision answered (the episode's current one).
            response: one of the decision's ``expects``.
            service: the service named (``answered`` a ``query_type``, a ``human_request``).
            detail: the detail named (``answered`` a ``query_detail``, a ``human_request``).
            feedback: ``"positive"`` or ``"negative"``: explicit feedback given with it.

        Raises:
            UnprocessableEntityError: a response the decision does not allow.
            ConflictError: another outcome for that decision, or not the current decision.
            EpisodeInterruptedError: (a ``ConflictError``) the episode was interrupted when its
                fleet's mission changed; it takes no more outcomes. Queued, such an outcome
                is rejected at delivery (``FlushReport.interrupted``), never retried.
            NotFoundError: no such episode.
        """
        return self._report(
            Api.report_outcome(
                episode_id,
                decision_id=decision_id,
                response=response,
                service=service,
                detail=detail,
                feedback=feedback,
            )
        )

    def send_feedback(
        self, episode_id: str, *, feedback_id: str, feedback: Feedback
    ) -> FeedbackResult | Queued:
        """``POST /v1/episodes/{episode_id}/feedback``: explicit feedback (``"positive"`` or
        ``"negative"``) on an episode, during or after it; idempotent on ``feedback_id``.

        With an outbox, it is queued like an outcome when the service cannot take it now.

        Raises:
            ConflictError: the ``feedback_id`` was used with other feedback, or the episode
                has no answered step yet.
            NotFoundError: no such episode.
        """
        return self._report(
            Api.send_feedback(episode_id, feedback_id=feedback_id, feedback=feedback)
        )

    def get_episode(self, episode_id: str) -> EpisodeTrace:
        """``GET /v1/episodes/{episode_id}``: the whole trace of an episode.

        Raises:
            NotFoundError: no such episode in your fleet.
        """
        return self._call(Api.get_episode(episode_id))

    def list_episodes(
        self, user_id: str, *, limit: int = 50, cursor: str | None = None
    ) -> EpisodePage:
        """``GET /v1/users/{user_id}/episodes``: one page of a user's episodes, newest first.

        Raises:
            NotFoundError: no such user.
        """
        return self._call(Api.list_episodes(user_id, limit, cursor))

    def iter_episodes(self, user_id: str, *, page_size: int = 100) -> Iterator[EpisodeSummary]:
        """Every episode of a user, newest first, page after page of ``page_size``."""
        cursor: str | None = None
        while True:
            page = self.list_episodes(user_id, limit=page_size, cursor=cursor)
            yield from page.items
            if page.next_cursor is None:
                return
            cursor = page.next_cursor

    # -- inspection and administration -----------------------------------------------------------
    def get_model(
        self, user_id: str, *, time_slot: str | None = None, situation: str | None = None
    ) -> ModelView:
        """``GET /v1/users/{user_id}/model``: what the user's learner believes now, optionally
        for one time slot and/or situation only."""
        return self._call(Api.get_model(user_id, time_slot, situation))

    def get_stats(self, user_id: str, *, last: int | None = None) -> Stats:
        """``GET /v1/users/{user_id}/stats``: interaction and success rates, queries per
        mission and rewards over the user's last ``last`` episodes (all when None)."""
        return self._call(Api.get_stats(user_id, last))

    def reset_model(self, user_id: str, *, drop_corrections: bool = False) -> None:
        """``DELETE /v1/users/{user_id}/model`` (the fleet's staff, admins): forget what was
        learned, keep the history.

        Args:
            drop_corrections: lift the user's staff corrections too (``?corrections=drop``;
                they are then listed as ``lifted``); by default they stay in force.

        Raises:
            PermissionDeniedError: a robot key.
            NotFoundError: no such user in your fleet.
        """
        self._call(Api.reset_model(user_id, drop_corrections))

    def export_model(self, user_id: str) -> dict[str, Any]:
        """``GET /v1/users/{user_id}/model/export`` (admin): the model as a self-describing
        document that ``import_model`` accepts back, here or on another deployment."""
        return self._call(Api.export_model(user_id))

    def import_model(self, user_id: str, document: Mapping[str, Any]) -> ModelView:
        """``PUT /v1/users/{user_id}/model`` (admin): replace the model with an exported
        document; returns the model as it now is.

        Raises:
            UnprocessableEntityError: a document of another format or mission.
        """
        return self._call(Api.import_model(user_id, document))

    # -- the profile and staff corrections -------------------------------------------------------
    def get_profile(self, user_id: str) -> Profile:
        """``GET /v1/users/{user_id}/profile``: what the person is believed to want in each
        time slot and situation of the fleet's mission, how certain that is, what the robot
        will most likely do there, in plain words and in fields (robot keys, the fleet's staff,
        admins). ``profile.context(time_slot, situation)`` picks one entry.

        Raises:
            NotFoundError: no such user in your fleet.
        """
        return self._call(Api.get_profile(user_id))

    def list_corrections(self, user_id: str) -> CorrectionList:
        """``GET /v1/users/{user_id}/corrections``: every staff correction of the user, lifted
        ones too, oldest first.

        Raises:
            NotFoundError: no such user in your fleet.
        """
        return self._call(Api.list_corrections(user_id))

    def add_correction(
        self,
        user_id: str,
        *,
        correction_id: str,
        time_slot: str,
        situation: str,
        kind: CorrectionKind,
        service: str | None = None,
        detail: str | None = None,
        note: str | None = None,
    ) -> Correction:
        """``POST /v1/users/{user_id}/corrections``: correct what was learned about the user
        in one time slot and situation (the fleet's staff, admins). Idempotent on
        ``correction_id``: a repeat of the same correction returns it with ``replayed`` True.

        Args:
            correction_id: your id of the correction (``^[A-Za-z0-9._:-]{1,128}$``).
            kind: ``prefers`` (needs ``service`` and ``detail``: the robot brings it without
                asking until the person's own answers contradict it twice in a row),
                ``avoid`` (needs ``service``, optionally ``detail``: the robot never chooses
                it there) or ``quiet`` (no service: the robot never initiates there).
            note: why, for the people who read it later (up to 500 characters).

        Raises:
            UnprocessableEntityError: an unknown time slot, situation, service or detail, or
                what ``kind`` needs missing.
            ConflictError: ``correction_id`` already used for another correction.
            PermissionDeniedError: a robot key.
            NotFoundError: no such user in your fleet.
        """
        return self._call(
            Api.add_correction(
                user_id,
                correction_id=correction_id,
                time_slot=time_slot,
                situation=situation,
                kind=kind,
                service=service,
                detail=detail,
                note=note,
            )
        )

    def lift_correction(self, user_id: str, correction_id: str) -> None:
        """``DELETE /v1/users/{user_id}/corrections/{correction_id}``: take a correction out
        of force (the fleet's staff, admins); the learner's own beliefs decide again. Lifting
        a lifted correction changes nothing.

        Raises:
            NotFoundError: no such correction, or no such user in your fleet.
            PermissionDeniedError: a robot key.
        """
        self._call(Api.lift_correction(user_id, correction_id))

    # -- changes told to staff -----------------------------------------------------------------
    def list_changes(
        self, user_id: str, *, limit: int = 50, cursor: str | None = None
    ) -> ChangeList:
        """``GET /v1/users/{user_id}/changes``: one page of the changes in what the person
        wants, newest first (the fleet's staff, admins). Each ``ChangeEvent`` says in which
        time slot and situation, since which episode and decided at which, what they wanted
        before and what now, on what evidence, and in words (``summary``). Pass the page's
        ``next_cursor`` as ``cursor`` for the next. The service records the read as a look at
        the person's data.

        Raises:
            PermissionDeniedError: a robot key.
            NotFoundError: no such user in your fleet.
        """
        return self._call(Api.list_changes(user_id, limit, cursor))

    def iter_changes(self, user_id: str, *, page_size: int = 100) -> Iterator[ChangeEvent]:
        """Every change of a user, newest first, page after page of ``page_size`` (the
        fleet's staff, admins); see ``list_changes``."""
        cursor: str | None = None
        while True:
            page = self.list_changes(user_id, limit=page_size, cursor=cursor)
            yield from page.items
            if page.next_cursor is None:
                return
            cursor = page.next_cursor

    def list_fleet_changes(
        self,
        fleet: str,
        *,
        since: dt.datetime | str | None = None,
        limit: int = 50,
        cursor: str | None = None,
    ) -> ChangeList:
        """``GET /v1/admin/fleets/{fleet}/changes``: one page of the changes in what the
        fleet's people want, newest first, each a ``ChangeEvent`` as ``list_changes`` gives it
        (the fleet's staff, admins). Each person the page lists is recorded as looked at.

        Args:
            fleet: whose people.
            since: only the changes decided at or after this time (an aware ``datetime`` or
                RFC 3339 text with an offset), e.g. a week ago for what changed this week.
            limit: changes per page, 1 to 500.
            cursor: the ``next_cursor`` of the previous page.

        Raises:
            PermissionDeniedError: a robot key, or staff of another fleet.
            UnprocessableEntityError: ``since`` without an offset, a bad ``limit`` or
                ``cursor``.
            ValueError: ``since`` is a naive ``datetime``.
        """
        return self._call(Api.list_fleet_changes(fleet, since, limit, cursor))

    def iter_fleet_changes(
        self, fleet: str, *, since: dt.datetime | str | None = None, page_size: int = 100
    ) -> Iterator[ChangeEvent]:
        """Every change of a fleet's people (decided at or after ``since``, when given), newest
        first, page after page of ``page_size``; see ``list_fleet_changes``."""
        cursor: str | None = None
        while True:
            page = self.list_fleet_changes(fleet, since=since, limit=page_size, cursor=cursor)
            yield from page.items
            if page.next_cursor is None:
                return
            cursor = page.next_cursor


class AsyncClient(BaseClient):
    """An asynchronous client of the Attune v1 API, with the methods of ``Client`` as
    coroutines. Use it with ``async with``, or call ``aclose()``.

    The arguments are those of ``Client``, with an ``httpx.AsyncBaseTransport``.
    """

    def __init__(
        self,
        base_url: str,
        api_key: str,
        *,
        timeout: float | httpx.Timeout = DEFAULT_TIMEOUT,
        max_retries: int = DEFAULT_MAX_RETRIES,
        outbox: str | os.PathLike[str] | None = None,
        transport: httpx.AsyncBaseTransport | None = None,
        headers: Mapping[str, str] | None = None,
    ) -> None:
        super().__init__(base_url, api_key, max_retries=max_retries, outbox=outbox, headers=headers)
        self._http = httpx.AsyncClient(
            base_url=base_url, timeout=timeout, transport=transport, headers=self._headers()
        )
        self._lock = anyio.Lock()
        self._sleep: Callable[[float], Awaitable[None]] = anyio.sleep

    @property
    def timeout(self) -> httpx.Timeout:
        """The timeout of every attempt."""
        return self._http.timeout

    async def aclose(self) -> None:
        """Close the connections and the outbox file (queued reports stay in it)."""
        await self._http.aclose()
        if self._outbox is not None:
            self._outbox.close()

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.aclose()

    # -- sending -------------------------------------------------------------------------------
    async def _send(self, request: httpx.Request, *, max_retries: int) -> httpx.Response:
        attempt = 0
        while True:
            try:
                response = await self._http.send(request)
            except httpx.TransportError as exc:
                if attempt >= max_retries:
                    raise transport_error(exc, request) from exc
                delay = self._backoff.delay(attempt, None, self._random)
            else:
                if response.is_success:
                    return response
                if attempt >= max_retries or not should_retry_status(response.status_code):
                    raise make_status_error(response)
                delay = self._backoff.delay(attempt, response, self._random)
            await self._sleep(delay)
            attempt += 1

    async def _queued(self) -> int:
        if self._outbox is None:
            return 0
        return await anyio.to_thread.run_sync(self._outbox.count)

    async def _call(self, op: Op[T], *, retries: int | None = None) -> T:
        # Deliver the queue first, unless another task is busy with it (or with a report).
        if await self._queued():
            try:
                self._lock.acquire_nowait()
            except anyio.WouldBlock:
                pass
            else:
                try:
                    await self._deliver(max_retries=0, wait=False, strict=False)
                finally:
                    self._lock.release()
        request = self._build(self._http, op)
        response = await self._send(
            request, max_retries=self.max_retries if retries is None else retries
        )
        return op.parse(response)

    async def _report(self, op: ReportOp[T]) -> T | Queued:
        request = self._build(self._http, op)
        outbox = self._outbox
        if outbox is None:
            return op.parse(await self._send(request, max_retries=self.max_retries))
        async with self._lock:
            if await self._queued():
                await self._deliver(max_retries=0, wait=False, strict=False)
            if await self._queued():  # keep the order: behind the reports still waiting
                return await anyio.to_thread.run_sync(
                    lambda: outbox.append(op.kind, op.episode_id, op.key, op.body)
                )
            try:
                response = await self._send(request, max_retries=self.max_retries)
            except AttuneError as exc:
                if not is_transient(exc):
                    raise
                error = str(exc)
                return await anyio.to_thread.run_sync(
                    lambda: outbox.append(
                        op.kind,
                        op.episode_id,
                        op.key,
                        op.body,
                        attempts=self.max_retries + 1,
                        last_error=error,
                    )
                )
        return op.parse(response)

    async def _deliver(self, *, max_retries: int, wait: bool, strict: bool) -> None:
        """As ``Client._deliver``; the file is used from worker threads, one at a time."""
        outbox = self._outbox
        assert outbox is not None
        run = anyio.to_thread.run_sync
        while True:
            if not await run(functools.partial(outbox.begin, wait=wait)):
                return
            try:
                head = await run(outbox.head)
                if head is None:
                    await run(outbox.commit)
                    return
                entry, body = head
                op = self._entry_op(entry, body)
                try:
                    response = await self._send(
                        self._build(self._http, op), max_retries=max_retries
                    )
                except AttuneError as exc:
                    refused = refusal(exc)
                    if refused is not None:
                        why = rejection(refused)
                        await run(outbox.reject, entry, why)
                        await run(outbox.commit)
                        self._rejected.append((entry, why))
                        continue
                    tries = max_retries + 1 if is_transient(exc) else 1
                    await run(outbox.note_failure, entry.seq, str(exc), tries)
                    await run(outbox.commit)
                    if strict and not is_transient(exc):
                        raise
                    return
                await run(outbox.remove, entry.seq)
                await run(outbox.commit)
            except BaseException:
                with anyio.CancelScope(shield=True):
                    await run(outbox.rollback)
                raise
            self._delivered.append((entry, op.parse(response)))

    # -- the outbox ----------------------------------------------------------------------------
    async def flush(self) -> FlushReport:
        """Deliver the outbox now; see ``Client.flush``."""
        if self._outbox is not None:
            async with self._lock:
                await self._deliver(max_retries=self.max_retries, wait=True, strict=True)
        async with self._lock:
            return await anyio.to_thread.run_sync(self._take_report)

    async def pending(self) -> list[PendingReport]:
        """The reports waiting in the outbox, oldest first; see ``Client.pending``."""
        if self._outbox is None:
            return []
        return await anyio.to_thread.run_sync(self._outbox.entries)

    async def rejected(self) -> list[tuple[PendingReport, Rejection]]:
        """The outbox's reports the service refused for good; see ``Client.rejected``."""
        if self._outbox is None:
            return []
        return await anyio.to_thread.run_sync(self._outbox.rejected)

    # -- service -------------------------------------------------------------------------------
    async def health(self) -> bool:
        """``GET /healthz``; see ``Client.health``."""
        try:
            return await self._call(Api.health(), retries=0)
        except AttuneError:
            return False

    async def ready(self) -> bool:
        """``GET /readyz``; see ``Client.ready``."""
        try:
            return await self._call(Api.ready(), retries=0)
        except AttuneError:
            return False

    async def mission(self, fleet: str | None = None) -> FleetMission:
        """``GET /v1/mission``; see ``Client.mission``."""
        return await self._call(Api.mission(fleet))

    async def missions(self, fleet: str) -> MissionVersionList:
        """``GET /v1/admin/fleets/{fleet}/missions``; see ``Client.missions``."""
        return await self._call(Api.missions(fleet))

    async def fleet_prior(self, fleet: str) -> FleetPrior:
        """``GET /v1/admin/fleets/{fleet}/prior``; see ``Client.fleet_prior``."""
        return await self._call(Api.fleet_prior(fleet))

    async def set_fleet_prior(self, fleet: str, *, enabled: bool) -> FleetPrior:
        """``PUT /v1/admin/fleets/{fleet}/prior``; see ``Client.set_fleet_prior``."""
        return await self._call(Api.set_fleet_prior(fleet, enabled))

    async def set_mission(
        self,
        fleet: str,
        mission: Mission | Mapping[str, Any],
        *,
        change_id: str | None = None,
        renames: MissionRenames | Mapping[str, Any] | None = None,
    ) -> MissionChanged:
        """``PUT /v1/admin/fleets/{fleet}/mission``; see ``Client.set_mission``."""
        return await self._call(Api.set_mission(fleet, mission, change_id, renames))

    # -- users ---------------------------------------------------------------------------------
    async def put_user(
        self,
        user_id: str,
        *,
        display_name: str | None = None,
        learner: LearnerSpec | Mapping[str, Any] | None = None,
        reset_model: bool = False,
        fleet_prior: bool | None = None,
    ) -> User:
        """``PUT /v1/users/{user_id}``; see ``Client.put_user``."""
        return await self._call(
            Api.put_user(user_id, display_name, learner, reset_model, fleet_prior)
        )

    async def get_user(self, user_id: str) -> User:
        """``GET /v1/users/{user_id}``; see ``Client.get_user``."""
        return await self._call(Api.get_user(user_id))

    async def list_users(self, *, limit: int = 50, cursor: str | None = None) -> UserPage:
        """``GET /v1/users``; see ``Client.list_users``."""
        return await self._call(Api.list_users(limit, cursor))

    async def iter_users(self, *, page_size: int = 100) -> AsyncIterator[User]:
        """Every user, page after page; see ``Client.iter_users``."""
        cursor: str | None = None
        while True:
            page = await self.list_users(limit=page_size, cursor=cursor)
            for user in page.items:
                yield user
            if page.next_cursor is None:
                return
            cursor = page.next_cursor

    async def delete_user(self, user_id: str) -> None:
        """``DELETE /v1/users/{user_id}`` (admin); see ``Client.delete_user``."""
        await self._call(Api.delete_user(user_id))

    # -- episodes ------------------------------------------------------------------------------
    async def start_episode(
        self,
        user_id: str,
        *,
        event_id: str,
        occurred_at: dt.datetime | str,
        situation: str,
        initiator: Initiator = "robot",
        request: ServiceRequest | Mapping[str, Any] | None = None,
        robot_id: str | None = None,
    ) -> EpisodeStarted:
        """``POST /v1/users/{user_id}/episodes``; see ``Client.start_episode``."""
        return await self._call(
            Api.start_episode(
                user_id,
                event_id=event_id,
                occurred_at=occurred_at,
                situation=situation,
                initiator=initiator,
                request=request,
                robot_id=robot_id,
            )
        )

    async def report_outcome(
        self,
        episode_id: str,
        *,
        decision_id: str,
        response: OutcomeResponse,
        service: str | None = None,
        detail: str | None = None,
        feedback: Feedback | None = None,
    ) -> OutcomeResult | Queued:
        """``POST /v1/episodes/{episode_id}/outcomes``; see ``Client.report_outcome``."""
        return await self._report(
            Api.report_outcome(
                episode_id,
                decision_id=decision_id,
                response=response,
                service=service,
                detail=detail,
                feedback=feedback,
            )
        )

    async def send_feedback(
        self, episode_id: str, *, feedback_id: str, feedback: Feedback
    ) -> FeedbackResult | Queued:
        """``POST /v1/episodes/{episode_id}/feedback``; see ``Client.send_feedback``."""
        return await self._report(
            Api.send_feedback(episode_id, feedback_id=feedback_id, feedback=feedback)
        )

    async def get_episode(self, episode_id: str) -> EpisodeTrace:
        """``GET /v1/episodes/{episode_id}``; see ``Client.get_episode``."""
        return await self._call(Api.get_episode(episode_id))

    async def list_episodes(
        self, user_id: str, *, limit: int = 50, cursor: str | None = None
    ) -> EpisodePage:
        """``GET /v1/users/{user_id}/episodes``; see ``Client.list_episodes``."""
        return await self._call(Api.list_episodes(user_id, limit, cursor))

    async def iter_episodes(
        self, user_id: str, *, page_size: int = 100
    ) -> AsyncIterator[EpisodeSummary]:
        """Every episode of a user, newest first; see ``Client.iter_episodes``."""
        cursor: str | None = None
        while True:
            page = await self.list_episodes(user_id, limit=page_size, cursor=cursor)
            for episode in page.items:
                yield episode
            if page.next_cursor is None:
                return
            cursor = page.next_cursor

    # -- inspection and administration -----------------------------------------------------------
    async def get_model(
        self, user_id: str, *, time_slot: str | None = None, situation: str | None = None
    ) -> ModelView:
        """``GET /v1/users/{user_id}/model``; see ``Client.get_model``."""
        return await self._call(Api.get_model(user_id, time_slot, situation))

    async def get_stats(self, user_id: str, *, last: int | None = None) -> Stats:
        """``GET /v1/users/{user_id}/stats``; see ``Client.get_stats``."""
        return await self._call(Api.get_stats(user_id, last))

    async def reset_model(self, user_id: str, *, drop_corrections: bool = False) -> None:
        """``DELETE /v1/users/{user_id}/model``; see ``Client.reset_model``."""
        await self._call(Api.reset_model(user_id, drop_corrections))

    async def export_model(self, user_id: str) -> dict[str, Any]:
        """``GET /v1/users/{user_id}/model/export`` (admin); see ``Client.export_model``."""
        return await self._call(Api.export_model(user_id))

    async def import_model(self, user_id: str, document: Mapping[str, Any]) -> ModelView:
        """``PUT /v1/users/{user_id}/model`` (admin); see ``Client.import_model``."""
        return await self._call(Api.import_model(user_id, document))

    # -- the profile and staff corrections -------------------------------------------------------
    async def get_profile(self, user_id: str) -> Profile:
        """``GET /v1/users/{user_id}/profile``; see ``Client.get_profile``."""
        return await self._call(Api.get_profile(user_id))

    async def list_corrections(self, user_id: str) -> CorrectionList:
        """``GET /v1/users/{user_id}/corrections``; see ``Client.list_corrections``."""
        return await self._call(Api.list_corrections(user_id))

    async def add_correction(
        self,
        user_id: str,
        *,
        correction_id: str,
        time_slot: str,
        situation: str,
        kind: CorrectionKind,
        service: str | None = None,
        detail: str | None = None,
        note: str | None = None,
    ) -> Correction:
        """``POST /v1/users/{user_id}/corrections``; see ``Client.add_correction``."""
        return await self._call(
            Api.add_correction(
                user_id,
                correction_id=correction_id,
                time_slot=time_slot,
                situation=situation,
                kind=kind,
                service=service,
                detail=detail,
                note=note,
            )
        )

    async def lift_correction(self, user_id: str, correction_id: str) -> None:
        """``DELETE /v1/users/{user_id}/corrections/{correction_id}``; see
        ``Client.lift_correction``."""
        await self._call(Api.lift_correction(user_id, correction_id))

    # -- changes told to staff -----------------------------------------------------------------
    async def list_changes(
        self, user_id: str, *, limit: int = 50, cursor: str | None = None
    ) -> ChangeList:
        """``GET /v1/users/{user_id}/changes``; see ``Client.list_changes``."""
        return await self._call(Api.list_changes(user_id, limit, cursor))

    async def iter_changes(
        self, user_id: str, *, page_size: int = 100
    ) -> AsyncIterator[ChangeEvent]:
        """Every change of a user, newest first; see ``Client.iter_changes``."""
        cursor: str | None = None
        while True:
            page = await self.list_changes(user_id, limit=page_size, cursor=cursor)
            for change in page.items:
                yield change
            if page.next_cursor is None:
                return
            cursor = page.next_cursor

    async def list_fleet_changes(
        self,
        fleet: str,
        *,
        since: dt.datetime | str | None = None,
        limit: int = 50,
        cursor: str | None = None,
    ) -> ChangeList:
        """``GET /v1/admin/fleets/{fleet}/changes``; see ``Client.list_fleet_changes``."""
        return await self._call(Api.list_fleet_changes(fleet, since, limit, cursor))

    async def iter_fleet_changes(
        self, fleet: str, *, since: dt.datetime | str | None = None, page_size: int = 100
    ) -> AsyncIterator[ChangeEvent]:
        """Every change of a fleet's people, newest first; see ``Client.iter_fleet_changes``."""
        cursor: str | None = None
        while True:
            page = await self.list_fleet_changes(fleet, since=since, limit=page_size, cursor=cursor)
            for change in page.items:
                yield change
            if page.next_cursor is None:
                return
            cursor = page.next_cursor
