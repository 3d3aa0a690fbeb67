"""The console's pages, under ``/admin``, rendered on the server.

Every page reads the services behind the v1 API (``app.services.*``) in the request's own
transaction (given by the route class), exactly as the API's routes do, so the console adds no
second source of truth: what a page shows for a user is what ``GET /v1/users/{id}/profile``,
``/corrections``, ``/model``, ``/stats`` and ``GET /v1/episodes/{id}`` return; the users list adds
each user's recent success rate and last activity (``app.services.console``, with the same
definitions as ``/stats``). A correction made on a person's profile is the same call as
``POST /v1/users/{id}/corrections``, with the signed-in key as its author.
"""

from __future__ import annotations

import datetime as dt
import re
import secrets
import zoneinfo
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Annotated, Any
from urllib.parse import quote, urlencode

import jinja2
from fastapi import APIRouter, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse, RedirectResponse, StreamingResponse
from fastapi.templating import Jinja2Templates
from pydantic import ValidationError

from app.api.deps import RequestSession, TransactionalRoute, writes
from app.api.errors import validation_detail
from app.api.middleware import HEAD_KEY
from app.api.routes._common import export_response
from app.errors import AppError, Conflict, NotFound, ValidationFailed
from app.learning import Mission
from app.learning.offpolicy import ESTIMATORS
from app.schemas.common import CLIENT_ID_PATTERN, MAX_POSITION
from app.schemas.profile import CorrectionIn
from app.schemas.users import UserOut
from app.services import admin as admin_service
from app.services import changes as changes_service
from app.services import console as console_service
from app.services import corrections as corrections_service
from app.services import episodes as episodes_service
from app.services import evaluation_jobs as evaluation_service
from app.services import missions as missions_service
from app.services import models as models_service
from app.services import profile as profile_service
from app.services import retention as retention_service
from app.services import rollouts as rollouts_service
from app.services import shadows as shadows_service
from app.services import subject as subject_service
from app.services import users as users_service
from app.services import views as data_views
from app.services.context import ServiceContext
from app.services.evaluation import CandidateSpec, parse_candidate

from . import views
from .auth import (
    CONSOLE_PATH,
    COOKIE,
    Admin,
    AdminDep,
    FormDep,
    LoginRequired,
    PageError,
    check_post,
    console_url,
    csrf_token,
    safe_next,
    same_origin,
    sign_in,
)
from .mission_form import FIELDS, FormError, MissionForm, changes, field_of, history

__all__ = ["router", "templates"]

HERE = Path(__file__).parent
templates = Jinja2Templates(directory=str(HERE / "templates"))
templates.env.globals["v"] = views


@jinja2.pass_context
def _url(context: jinja2.runtime.Context, path: str = "") -> str:
    """``url("/users")`` in a template: the console's ``path`` under the request's root path."""
    return console_url(context["request"], path)


templates.env.globals["url"] = _url
templates.env.globals["recent_episodes"] = console_service.RECENT_EPISODES

_HEADERS = {
    # The pages load nothing but their own files: no inline script or style, no framing (the
    # reset and delete buttons must not be clickjacked), nothing cached (people's data).
    "Content-Security-Policy": "default-src 'self'; script-src 'self'; style-src 'self'; "
    "img-src 'self' data:; object-src 'none'; base-uri 'none'; "
    "form-action 'self'; frame-ancestors 'none'",
    "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "same-origin",
    "Cache-Control": "no-store",
}
_USER_ID = re.compile(CLIENT_ID_PATTERN)
_TITLES = {
    400: "Bad request",
    401: "Sign in again",
    403: "Not allowed",
    404: "Not found",
    409: "Conflict",
    422: "Not valid",
    503: "Busy, retry",
}


def _error_page(request: Request, status: int, title: str, detail: str) -> HTMLResponse:
    return templates.TemplateResponse(
        request,
        "error.html",
        {
            "title": title,
            "detail": detail,
            "status": status,
            "admin": None,
        },
        status_code=status,
    )


class ConsoleRoute(TransactionalRoute):
    """Turns the console's refusals and the services' errors into pages (the v1 API's handlers
    answer JSON), and adds the pages' security headers."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def route(request: Request) -> Response:
            response: Response
            try:
                response = await handler(request)
            except LoginRequired as exc:
                response = _redirect(request, f"/login?next={_quote(exc.next_path)}")
            except PageError as exc:
                response = _error_page(request, exc.status, exc.title, exc.detail)
                if exc.sign_out:
                    _forget(request, response)
            except AppError as exc:
                response = _error_page(
                    request, exc.status_code, _TITLES.get(exc.status_code, "Error"), exc.detail
                )
            except RequestValidationError as exc:
                response = _error_page(request, 422, "Bad address", validation_detail(request, exc))
            response.headers.update(_HEADERS)
            return response

        return route


def _quote(path: str) -> str:
    return quote(path, safe="/")


def _forget(request: Request, response: Response) -> None:
    response.delete_cookie(
        COOKIE, path=console_url(request), httponly=True, samesite="strict", secure=_https(request)
    )


def _https(request: Request) -> bool:
    """The browser asked over https (as a trusted proxy forwards it): the cookie is Secure."""
    return request.url.scheme == "https"


def _page(
    request: Request, name: str, admin: Admin | None, status: int = 200, **context: Any
) -> HTMLResponse:
    return templates.TemplateResponse(
        request, name, {"admin": admin, **context}, status_code=status
    )


def _redirect(request: Request, path: str) -> RedirectResponse:
    """303 to the console's ``path`` (``/users``), under the root path."""
    return RedirectResponse(console_url(request, path), status_code=303)


FleetQuery = Annotated[str | None, Query(max_length=128, pattern=CLIENT_ID_PATTERN)]


router = APIRouter(prefix=CONSOLE_PATH, route_class=ConsoleRoute, include_in_schema=False)


def _check_user_id(user_id: str) -> None:
    if not _USER_ID.match(user_id):
        raise PageError(
            404, "Not found", f"No user {user_id!r}: user ids use letters, digits and . _ : - only."
        )


# -- signing in and out --------------------------------------------------------------------------
@router.get("")
def home(request: Request) -> RedirectResponse:
    """The console's front page is the users list."""
    return _redirect(request, "/users")


@router.get("/login")
def login_form(
    request: Request,
    next: Annotated[str | None, Query(max_length=2000)] = None,
    signed_out: bool = False,
) -> HTMLResponse:
    """The sign-in form: an admin key."""
    return _page(
        request,
        "login.html",
        None,
        next=safe_next(next, console_url(request)),
        error=None,
        signed_out=signed_out,
    )


@router.post("/login")
async def login(request: Request, form: FormDep) -> Response:
    """Check the key; keep it in a browser-session cookie; go where the person was heading."""
    target = safe_next(form.get("next"), console_url(request))
    if not same_origin(request):
        raise PageError(403, "Request refused", "Sign in from the console's own login page.")
    secret = form.get("key", "").strip()
    try:
        if not secret:
            raise PageError(401, "Key needed", "Paste an admin key to sign in.")
        await sign_in(request, secret)
    except PageError as exc:
        return _page(
            request, "login.html", None, exc.status, next=target, error=exc, signed_out=False
        )
    response = RedirectResponse(target, status_code=303)  # already under the root path
    # No Max-Age or Expires: a session cookie, gone when the browser closes.
    response.set_cookie(
        COOKIE,
        secret,
        path=console_url(request),
        httponly=True,
        samesite="strict",
        secure=_https(request),
    )
    return response


@router.post("/logout")
def logout(request: Request, form: FormDep) -> Response:
    """Forget the key in this browser."""
    secret = request.cookies.get(COOKIE)
    if secret and (not same_origin(request) or form.get("csrf") != csrf_token(secret)):
        raise PageError(403, "Request refused", "Sign out from a console page.")
    response = _redirect(request, "/login?signed_out=true")
    _forget(request, response)
    return response


# -- users -----------------------------------------------------------------------------------
@router.get("/users")
def users_page(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    q: Annotated[str | None, Query(max_length=200)] = None,
    page: Annotated[int, Query(ge=1, le=1_000_000)] = 1,
    per_page: Annotated[int, Query(ge=5, le=200)] = 25,
    deleted: Annotated[str | None, Query(max_length=128)] = None,
) -> HTMLResponse:
    """Users, searchable, a page at a time, with learner, episodes, recent success, activity."""
    found = console_service.find_users(
        session, admin.principal, text=q, page=page, per_page=per_page
    )
    shown = deleted if deleted and _USER_ID.match(deleted) else None  # only ids: no free text
    zones = console_service.time_zones(session, ctx, {row.user.fleet for row in found.items})
    return _page(
        request,
        "users.html",
        admin,
        found=found,
        q=q or "",
        deleted=shown,
        nav="users",
        zones=zones,
    )


def _counts(session: RequestSession, user: UserOut) -> dict[str, int]:
    """The header's episode count: all of the person's episodes, the open ones said apart."""
    return {
        "episodes": user.episodes,
        "open_episodes": console_service.open_episodes(session, user),
    }


def _looked(
    request: Request,
    session: RequestSession,
    admin: Admin,
    user: UserOut,
    page: str | None,
) -> list[Any]:
    """Record that this staff member or admin opens ``page`` of the person (who looked:
    ``app.services.views``), and the few who looked before them, newest first, for the
    page's header. ``page`` None: the page records its own look (or none), only list them."""
    before = data_views.list_views(
        session,
        admin.principal,
        limit=LOOKED_SHOWN,
        cursor=None,
        user_id=user.user_id,
        fleet=user.fleet,
    ).items
    if page is None or request.scope.get(HEAD_KEY):  # a HEAD sends no data: nothing looked at
        return before
    data_views.record(
        request.app.state.db,
        request.app.state.settings,
        admin.principal,
        user_id=user.user_id,
        fleet=user.fleet,
        what=f"console.{page}",
        via="console",
    )
    return before


LOOKED_SHOWN = 3  # the header's "looked at by" entries


_SLOT_NAME = Annotated[str | None, Query(max_length=64)]
_CORRECTION_KINDS = ("prefers", "avoid", "quiet")
_CORRECTION_FIELDS = ("kind", "service", "detail", "note")
_NO_KIND = (
    "Choose what to correct: what the person prefers, what the robot "
    "should not offer, or that the robot should stay quiet here."
)


def _profile_page(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: Admin,
    user: UserOut,
    *,
    time_slot: str | None,
    situation: str | None,
    done: str | None = None,
    typed: dict[str, str] | None = None,
    error: str | None = None,
    status: int = 200,
    looked: list[Any] | None = None,
) -> HTMLResponse:
    principal = admin.principal
    profile = profile_service.profile_view(session, ctx, principal, user.user_id, fleet=user.fleet)
    mission = console_service.user_mission(session, ctx, user)
    grid = views.profile_grid(profile, mission)
    selected = None
    if time_slot is not None and situation is not None:
        selected = next(
            (
                c
                for row in grid
                for c in row.cells
                if (c.time_slot, c.situation) == (time_slot, situation)
            ),
            None,
        )
    changed = changes_service.person_changes(
        session, ctx, principal, user.user_id, limit=CHANGES_SHOWN, cursor=None, fleet=user.fleet
    ).items
    in_force = {c.correction_id: c for c in profile.corrections}
    here = []
    if selected is not None and selected.context is not None:
        here = [in_force[i] for i in selected.context.corrections if i in in_force]
    return _page(
        request,
        "user.html",
        admin,
        status,
        user=user,
        tab="profile",
        profile=profile,
        grid=grid,
        selected=selected,
        here=here,
        mission=mission,
        counts={"episodes": profile.episodes, "open_episodes": profile.open_episodes},
        done=done,
        typed=typed or {},
        error=error,
        correction_id=secrets.token_hex(16),
        mission_version=console_service.mission_version(session, user),
        zone=mission.time_zone,
        key_names=console_service.key_names(session, [c.author for c in profile.corrections]),
        looked=looked,
        history_from=console_service.history_from(session, user),
        changes=changed,
        evidence=console_service.evidence_episodes(session, user.fleet, changed),
        now_of={(c.time_slot, c.situation): c for c in profile.contexts},
    )


@router.get("/users/{user_id}")
def user_page(
    request: Request,
    user_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    time_slot: _SLOT_NAME = None,
    situation: _SLOT_NAME = None,
    done: Annotated[str | None, Query(max_length=32)] = None,
    fleet: FleetQuery = None,
) -> HTMLResponse:
    """What the person wants, when, and what the robot will do, in words; a chosen cell
    (``time_slot`` and ``situation``) shows the evidence and the form that corrects it."""
    _check_user_id(user_id)
    user = users_service.get_user(session, admin.principal, user_id, fleet=fleet)
    looked = _looked(request, session, admin, user, "profile")
    return _profile_page(
        request,
        session,
        ctx,
        admin,
        user,
        time_slot=time_slot,
        situation=situation,
        done=done,
        looked=looked,
    )


def _correction_error(exc: ValidationError) -> str:
    problems = []
    for err in exc.errors():
        where = str(err["loc"][-1]) if err["loc"] else "form"
        problems.append(f"{where}: {err['msg']}")
    return "The correction could not be read (" + "; ".join(problems) + ")."


@router.post("/users/{user_id}/corrections")
def add_correction(
    request: Request,
    user_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> Response:
    """Correct what was learned about the person in one context (as POST
    /v1/users/{id}/corrections, with this key as the author), then back to the profile. A
    mistake comes back on the form, in words, with what was typed."""
    _check_user_id(user_id)
    check_post(request, admin, form)
    principal = admin.principal
    time_slot, situation = form.get("time_slot", ""), form.get("situation", "")
    typed = {k: form.get(k, "") for k in _CORRECTION_FIELDS}
    kind = typed["kind"]
    service = typed["service"].strip() or None
    detail = typed["detail"].strip() or None
    if kind == "quiet":  # the form keeps its lists filled in; quiet takes neither
        service = detail = None

    def again(status: int, message: str) -> HTMLResponse:
        user = users_service.get_user(session, principal, user_id, fleet=fleet)
        return _profile_page(
            request,
            session,
            ctx,
            admin,
            user,
            time_slot=time_slot,
            situation=situation,
            typed=typed,
            error=message,
            status=status,
        )

    if kind not in _CORRECTION_KINDS:
        return again(422, _NO_KIND)
    try:
        body = CorrectionIn(
            correction_id=form.get("correction_id", ""),
            time_slot=time_slot,
            situation=situation,
            kind=kind,  # type: ignore[arg-type]
            service=service,
            detail=detail,
            note=typed["note"].strip() or None,
        )
    except ValidationError as exc:
        return again(422, _correction_error(exc))
    try:
        corrections_service.add_correction(session, ctx, principal, user_id, body, fleet=fleet)
    except corrections_service.CorrectionRefused as exc:
        held = users_service.get_user(session, principal, user_id, fleet=fleet)
        mission = console_service.user_mission(session, ctx, held)
        return again(422, views.refusal_words(exc.reasons, mission, held.fleet))
    except Conflict:
        return again(
            409,
            "This form was already used for another correction. Check the "
            "corrections below, then try again.",
        )
    user = views.UserAt(user_id, users_service.fleet_of(principal, fleet, user_id))
    return _redirect(
        request,
        views.user_url(user, time_slot=time_slot, situation=situation, done="corrected")
        + "#evidence",
    )


@router.post("/users/{user_id}/corrections/{correction_id}/lift")
def lift_correction(
    request: Request,
    user_id: str,
    correction_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> Response:
    """Lift a correction (as DELETE /v1/users/{id}/corrections/{correction_id}): the robot
    goes back to what it learned from the person."""
    _check_user_id(user_id)
    check_post(request, admin, form)
    user = users_service.get_user(session, admin.principal, user_id, fleet=fleet)
    if not _USER_ID.match(correction_id):
        raise PageError(404, "Not found", "No such correction.")
    try:
        lifted = corrections_service.lift_correction(
            session, ctx, admin.principal, user_id, correction_id, fleet=user.fleet
        )
    except NotFound:
        raise PageError(
            404,
            "Not found",
            f"{user.display_name or user.user_id} has no "
            "correction of that number; it may have been deleted with the "
            "person's history.",
        ) from None
    return _redirect(
        request,
        views.user_url(user, time_slot=lifted.time_slot, situation=lifted.situation, done="lifted")
        + "#evidence",
    )


@router.get("/users/{user_id}/details")
def details_page(
    request: Request,
    user_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    last: Annotated[int, Query(ge=1, le=1_000_000)] = console_service.RECENT_EPISODES,
    done: Annotated[str | None, Query(max_length=32)] = None,
    fleet: FleetQuery = None,
) -> HTMLResponse:
    """Details for engineers: the heatmap of P(initiate), the paper's metrics, the reward
    curve."""
    _check_user_id(user_id)
    principal = admin.principal
    user = users_service.get_user(session, principal, user_id, fleet=fleet)
    model = models_service.model_view(
        session, ctx, principal, user_id, time_slot=None, situation=None, fleet=user.fleet
    )
    overall = models_service.stats(session, principal, user_id, last=None, fleet=user.fleet)
    recent = models_service.stats(session, principal, user_id, last=last, fleet=user.fleet)
    xs, ys = views.curve(overall.cumulative_reward)
    mission = console_service.user_mission(session, ctx, user)
    looked = _looked(request, session, admin, user, "details")
    return _page(
        request,
        "details.html",
        admin,
        looked=looked,
        user=user,
        model=model,
        tab="details",
        heat=views.heatmap(model, mission),
        overall=overall,
        recent=recent,
        last=last,
        chart={"x": xs, "y": ys, "total": overall.total_reward, "episodes": overall.episodes},
        done=done,
        mission=mission,
        counts=_counts(session, user),
        history_from=console_service.history_from(session, user),
    )


@router.get("/users/{user_id}/why")
def why_page(
    request: Request,
    user_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    time_slot: Annotated[str | None, Query(max_length=64)] = None,
    situation: Annotated[str | None, Query(max_length=64)] = None,
    fleet: FleetQuery = None,
) -> HTMLResponse:
    """Why this action: every state's actions in one context, with the numbers behind P."""
    _check_user_id(user_id)
    principal = admin.principal
    user = users_service.get_user(session, principal, user_id, fleet=fleet)
    mission = console_service.user_mission(session, ctx, user)
    if time_slot is None or situation is None:
        latest = episodes_service.list_episodes(
            session, ctx, principal, user_id, limit=1, cursor=None, fleet=user.fleet
        ).items
        slot0, sit0 = (
            (latest[0].context.time_slot, latest[0].context.situation)
            if latest
            else mission.context_names(0)
        )
        time_slot, situation = time_slot or slot0, situation or sit0
    model = models_service.model_view(
        session, ctx, principal, user_id, time_slot=time_slot, situation=situation, fleet=user.fleet
    )
    context = model.contexts[0]
    corrections = corrections_service.list_corrections(
        session, ctx, principal, user_id, fleet=user.fleet
    ).items
    trace = console_service.latest_trace_in_context(
        session, ctx, principal, user_id, time_slot=time_slot, situation=situation, fleet=user.fleet
    )
    looked = _looked(request, session, admin, user, "why")
    return _page(
        request,
        "why.html",
        admin,
        looked=looked,
        user=user,
        model=model,
        tab="details",
        context=context,
        rows=views.why_rows(context),
        trace=trace,
        mission=mission,
        v_max=mission.v_max,
        counts=_counts(session, user),
        zone=mission.time_zone,
        drivers=views.drivers(
            model.started_from,
            [c for c in corrections if (c.time_slot, c.situation) == (time_slot, situation)],
            views.episodes_in(context),
        ),
        key_names=console_service.key_names(session, [c.author for c in corrections]),
        history_from=console_service.history_from(session, user),
    )


@router.get("/users/{user_id}/episodes")
def episodes_page(
    request: Request,
    user_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    before: Annotated[int | None, Query(ge=1, le=MAX_POSITION)] = None,
    at: Annotated[int | None, Query(ge=1, le=MAX_POSITION - 1)] = None,
    per_page: Annotated[int, Query(ge=5, le=200)] = 25,
    fleet: FleetQuery = None,
) -> HTMLResponse:
    """The user's episodes, newest first, a page at a time (``at``: from that episode on); each
    expands into its trace."""
    _check_user_id(user_id)
    if at is not None:
        before = at + 1
    principal = admin.principal
    user = users_service.get_user(session, principal, user_id, fleet=fleet)
    page = episodes_service.list_episodes(
        session,
        ctx,
        principal,
        user_id,
        limit=per_page,
        cursor=None if before is None else str(before),
        fleet=user.fleet,
    )
    newest = page.items[0].index if page.items else None
    newer = None
    if newest is not None and newest < user.episodes:
        newer = newest + per_page + 1 if newest + per_page < user.episodes else 0
    mission = console_service.user_mission(session, ctx, user)
    looked = _looked(request, session, admin, user, "episodes")
    return _page(
        request,
        "episodes.html",
        admin,
        looked=looked,
        user=user,
        tab="episodes",
        page=page,
        per_page=per_page,
        newer=newer,
        mission=mission,
        zone=mission.time_zone,
        older=int(page.next_cursor) if page.next_cursor else None,
        counts=_counts(session, user),
        history_from=console_service.history_from(session, user),
    )


@router.get("/users/{user_id}/episodes/{episode_id}/trace")
def trace_fragment(
    request: Request,
    user_id: str,
    episode_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
) -> HTMLResponse:
    """One episode's trace, as an HTML fragment for the episode list."""
    _check_user_id(user_id)
    if len(episode_id) > 128:
        raise PageError(404, "Not found", "No such episode.")
    user = users_service.get_user(session, admin.principal, user_id, fleet=fleet)
    trace = episodes_service.get_trace(session, ctx, admin.principal, episode_id)
    if trace.user_id != user_id or trace.fleet != user.fleet:
        raise PageError(404, "Not found", f"Episode {episode_id!r} is not {user_id!r}'s.")
    _looked(request, session, admin, user, "trace")
    mission = console_service.user_mission(session, ctx, user)
    return _page(
        request,
        "_trace.html",
        admin,
        trace=trace,
        user=user,
        mission=mission,
        zone=mission.time_zone,
    )


# Named as the API's export route on purpose: an export leaves an audit entry, and the session
# dependency opens a write transaction for the routes of that name.
@router.get("/users/{user_id}/export")
@writes  # an export is an admin action: it leaves an audit entry
def export_model(
    user_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
) -> JSONResponse:
    """Download the model document of GET /v1/users/{id}/model/export."""
    _check_user_id(user_id)
    doc = models_service.export_model(session, ctx, admin.principal, user_id, fleet=fleet)
    data_views.add(
        session,
        ctx.settings,
        admin.principal,
        fleet=users_service.fleet_of(admin.principal, fleet, user_id),
        user_id=user_id,
        what="export",
        via="console",
    )
    name = f"attune-model-{user_id.replace(':', '_')}.json"
    return JSONResponse(doc, headers={"Content-Disposition": f'attachment; filename="{name}"'})


@router.get("/users/{user_id}/everything")
@writes  # the export leaves an audit entry
def export_person(
    request: Request,
    user_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
) -> StreamingResponse:
    """Download everything stored about the person (as GET /v1/users/{id}/export)."""
    _check_user_id(user_id)
    started = subject_service.begin_export(session, ctx, admin.principal, user_id, fleet=fleet)
    return export_response(request, started, ctx)


# -- admin actions: a confirmation page, then a POST with the CSRF token ----------------------
_ACTIONS = {
    "reset": (
        "Start learning over",
        "Forget what was learned about {who}: the robot starts over as with a new person "
        "(a fresh {algorithm} learner). The history ({episodes} episodes) is kept, and "
        "so are the staff corrections in force (lift them on the profile first if they "
        "should go too).",
    ),
    "delete": (
        "Erase the person",
        "Erase everything stored about {who}: the whole history ({episodes} episodes), what "
        "the robots learned, feedback, and the staff corrections with their notes. The audit "
        "log keeps only that they were erased, by whom and when. This cannot be undone; "
        "export the model first if it may be needed again.",
    ),
}


def _confirm(
    request: Request,
    session: RequestSession,
    admin: Admin,
    user_id: str,
    action: str,
    fleet: str | None,
) -> HTMLResponse:
    _check_user_id(user_id)
    user = users_service.get_user(session, admin.principal, user_id, fleet=fleet)
    title, text = _ACTIONS[action]
    who = f"{user.display_name} ({user.user_id})" if user.display_name else user.user_id
    return _page(
        request,
        "confirm.html",
        admin,
        user=user,
        action=action,
        title=title,
        text=text.format(who=who, algorithm=user.learner.algorithm, episodes=user.episodes),
    )


@router.get("/users/{user_id}/reset")
def reset_confirm(
    request: Request,
    user_id: str,
    session: RequestSession,
    admin: AdminDep,
    fleet: FleetQuery = None,
) -> HTMLResponse:
    """Ask before resetting a user's model."""
    return _confirm(request, session, admin, user_id, "reset", fleet)


@router.post("/users/{user_id}/reset")
def reset(
    request: Request,
    user_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> RedirectResponse:
    """Reset the user's model (as DELETE /v1/users/{id}/model), keeping the history."""
    _check_user_id(user_id)
    check_post(request, admin, form)
    user = users_service.get_user(session, admin.principal, user_id, fleet=fleet)
    models_service.reset_model(session, ctx, admin.principal, user_id, fleet=user.fleet)
    return _redirect(request, views.user_url(user, "/details", done="reset"))


@router.get("/users/{user_id}/delete")
def delete_confirm(
    request: Request,
    user_id: str,
    session: RequestSession,
    admin: AdminDep,
    fleet: FleetQuery = None,
) -> HTMLResponse:
    """Ask before deleting a user."""
    return _confirm(request, session, admin, user_id, "delete", fleet)


@router.post("/users/{user_id}/delete")
def delete(
    request: Request,
    user_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> RedirectResponse:
    """Erase the person (as DELETE /v1/users/{id})."""
    _check_user_id(user_id)
    check_post(request, admin, form)
    users_service.delete_user(session, ctx, admin.principal, user_id, fleet=fleet)
    return _redirect(request, f"/users?deleted={user_id}")


# -- a fleet's pages (the mission, the history kept): the fleet in the address ------------------
def _fleet_choice(session: RequestSession, admin: Admin, fleet: str) -> list[str] | None:
    """The fleets an admin may pick on a fleet's page (``None`` for staff: their own only)."""
    if not admin.principal.is_admin:
        return None
    return sorted({f.fleet for f in admin_service.fleets(session, admin.principal).items} | {fleet})


def _fleet_url(page: str, fleet: str, **params: object) -> str:
    """A fleet's page's address in the console (``/mission?fleet=...``, for ``_redirect`` and
    ``console_url``)."""
    return f"{page}?" + urlencode(
        {"fleet": fleet, **{k: v for k, v in params.items() if v is not None}}
    )


# -- the fleet's mission: what it is, its versions, and a form to change it --------------------
_CHANGE_ID = re.compile(r"^[A-Za-z0-9_.:-]{1,128}$")


def _mission_page(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: Admin,
    fleet: str,
    *,
    form: MissionForm | None = None,
    change_id: str | None = None,
    preview: missions_service.ChangePreview | None = None,
    done: dict[str, Any] | None = None,
    status: int = 200,
) -> HTMLResponse:
    listed = missions_service.list_missions(session, ctx, admin.principal, fleet)  # may 403
    versions = history(listed["items"])
    current = versions[0]
    return _page(
        request,
        "mission.html",
        admin,
        status,
        nav="mission",
        fleet=fleet,
        fleets=_fleet_choice(session, admin, fleet),
        current=current,
        versions=versions,
        form=form or MissionForm.of(current.mission),
        change_id=change_id or secrets.token_hex(16),
        base_version=current.version if current.stored else 0,
        preview=preview,
        done=done,
        action=console_url(request, _fleet_url("/mission", fleet)),
        fields=FIELDS,
        preview_changes=changes(preview.old, preview.new, preview.diff) if preview else None,
    )


@router.get("/mission")
def mission_page(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
    done: Annotated[int | None, Query(ge=1, le=MAX_POSITION)] = None,
) -> HTMLResponse:
    """The fleet's mission in plain words, its versions with what each changed, and the form
    that sets a new one (staff: their fleet; admins: ``?fleet=``)."""
    name = fleet or admin.principal.fleet
    result = None
    if done is not None:
        result = missions_service.change_result(session, admin.principal, name, done)
    return _mission_page(request, session, ctx, admin, name, done=result)


@router.post("/mission")
def change_mission(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> Response:
    """``step=preview``: what the typed mission would change (nothing is stored);
    ``step=confirm``: store it as the fleet's new version (as PUT
    /v1/admin/fleets/{fleet}/mission), then back to the mission page. A mistake comes back on
    the form, next to the field, with what was typed."""
    check_post(request, admin, form)
    name = fleet or admin.principal.fleet
    principal = admin.principal
    listed = missions_service.list_missions(session, ctx, principal, name)
    current = Mission.from_dict(listed["items"][0]["mission"])
    base = listed["current_version"] if listed["items"][0]["stored"] else 0
    typed = MissionForm.from_fields(form, current)
    change_id = form.get("change_id", "")

    def again(status: int, where: str, message: str, *, new_id: bool = False) -> HTMLResponse:
        typed.errors[where] = message
        return _mission_page(
            request,
            session,
            ctx,
            admin,
            name,
            form=typed,
            status=status,
            change_id=None if new_id else change_id,
        )

    if not _CHANGE_ID.match(change_id):
        return again(
            400,
            "general",
            "The form is incomplete (its change number is missing). "
            "Check what you typed and preview again.",
            new_id=True,
        )
    try:
        mission_doc, renames_doc = typed.documents(current)
    except FormError as exc:
        return again(422, exc.field, exc.message)
    if form.get("step") == "confirm":
        earlier = missions_service.change_of(session, principal, name, change_id)
        if earlier is None and form.get("base_version") != str(base):
            return again(
                409,
                "general",
                f"The mission was changed meanwhile (it is now "
                f"version {listed['current_version']}). Check the preview again "
                "before applying.",
            )
        try:
            out, _ = missions_service.set_mission(
                session,
                ctx,
                principal,
                name,
                change_id=change_id,
                mission_doc=mission_doc,
                renames_doc=renames_doc,
            )
        except ValidationFailed as exc:
            return again(422, *field_of(exc.detail, mission_doc))
        except Conflict:
            return again(
                409,
                "general",
                "This form was already used for another change. "
                "Check the mission in force below, then preview again.",
                new_id=True,
            )
        return _redirect(request, _fleet_url("/mission", name, done=out["version"]))
    try:
        preview = missions_service.preview_change(
            session, ctx, principal, name, mission_doc=mission_doc, renames_doc=renames_doc
        )
    except ValidationFailed as exc:
        return again(422, *field_of(exc.detail, mission_doc))
    return _mission_page(
        request, session, ctx, admin, name, form=typed, change_id=change_id, preview=preview
    )


# -- what changed in what the fleet's people want ----------------------------------------------
CHANGES_SHOWN = 5  # a person's latest changes on their profile page
CHANGES_DAYS = (7, 30, 365)  # the periods the fleet's page offers


@router.get("/changes")
@writes  # each person the page names is recorded as looked at
def changes_page(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
    days: Annotated[int, Query(ge=1, le=366)] = 7,
) -> HTMLResponse:
    """What changed this week (or the last ``days`` days) in what the fleet's people want,
    newest first, in words, with the episodes that showed it (staff: their fleet; admins:
    ``?fleet=``)."""
    name = fleet or admin.principal.fleet
    since = dt.datetime.now(dt.UTC) - dt.timedelta(days=days)
    listed = changes_service.fleet_changes(
        session, ctx, admin.principal, name, since=since, limit=200, cursor=None, via="console"
    )  # may 403; each person named is recorded as looked at
    zone = console_service.time_zones(session, ctx, {name})[name]
    mission = ctx.missions.display(
        session, name, missions_service.current_version(session, ctx, name)
    )
    return _page(
        request,
        "changes.html",
        admin,
        nav="changes",
        fleet=name,
        fleets=_fleet_choice(session, admin, name),
        changes=listed.items,
        more=listed.next_cursor is not None,
        evidence=console_service.evidence_episodes(session, name, listed.items),
        days=days,
        periods=CHANGES_DAYS,
        zone=zone,
        mission=mission,
    )


# -- how long the fleet keeps its history: its retention window --------------------------------
_DAYS_TEXT = re.compile(r"^[0-9]{1,9}$")


def _retention_page(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: Admin,
    fleet: str,
    *,
    done: bool = False,
    typed: dict[str, str] | None = None,
    error: str | None = None,
    status: int = 200,
) -> HTMLResponse:
    window = retention_service.window_view(session, ctx, admin.principal, fleet)  # may 403
    zone = console_service.time_zones(session, ctx, {fleet})[fleet]
    return _page(
        request,
        "retention.html",
        admin,
        status,
        nav="retention",
        fleet=fleet,
        fleets=_fleet_choice(session, admin, fleet),
        window=window,
        zone=zone,
        set_by=(
            views.key_label(window.set_by, console_service.key_names(session, [window.set_by]))
            if window.set_by
            else None
        ),
        done=done,
        typed=typed,
        error=error,
        max_days=retention_service.MAX_DAYS,
        action=console_url(request, _fleet_url("/retention", fleet)),
    )


@router.get("/retention")
def retention_page(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
    done: Annotated[str | None, Query(max_length=16)] = None,
) -> HTMLResponse:
    """How long the fleet keeps its episodes, in words: the window, when the last clean-up ran
    and what it removed, and the form that sets the window (staff: their fleet; admins:
    ``?fleet=``)."""
    name = fleet or admin.principal.fleet
    return _retention_page(request, session, ctx, admin, name, done=done == "saved")


@router.post("/retention")
def set_retention(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> Response:
    """Set the fleet's window (as PUT /v1/admin/fleets/{fleet}/history, through the same
    service: validated and audited there), then back to the page. A mistake comes back on the
    form in words, with what was typed."""
    check_post(request, admin, form)
    name = fleet or admin.principal.fleet
    typed = {"keep": form.get("keep", ""), "days": form.get("days", "").strip()}

    def again(message: str) -> HTMLResponse:
        return _retention_page(
            request, session, ctx, admin, name, typed=typed, error=message, status=422
        )

    days: int | None = None
    if typed["keep"] == "days":
        if not _DAYS_TEXT.match(typed["days"]):
            return again(
                f"Write the number of days as a whole number, from 1 to "
                f"{retention_service.MAX_DAYS:,}."
            )
        days = int(typed["days"])
    elif typed["keep"] != "all":
        return again("Choose whether to keep every episode or to remove the older ones.")
    try:
        retention_service.set_history(session, ctx, admin.principal, name, days=days)
    except ValidationFailed:  # out of range: the service's rule, said in words here
        return again(
            f"{typed['days']} days cannot be set: the number of days goes from 1 to "
            f"{retention_service.MAX_DAYS:,} (a hundred years)."
        )
    return _redirect(request, _fleet_url("/retention", name, done="saved"))


# -- what if: candidate learners estimated from the fleet's logs (evaluations) ------------------
_EVALUATION_ID = re.compile(r"^ev_[0-9a-f]{32}$")
_DATE_TEXT = re.compile(r"^[0-9]{4}-[0-9]{2}-[0-9]{2}$")
EVALUATIONS_SHOWN = 20  # the fleet's newest evaluations on its page
_FORM_TEXT = ("other", "since", "until", "estimator")


def _check_evaluation_id(evaluation_id: str) -> None:
    if not _EVALUATION_ID.match(evaluation_id):
        raise PageError(404, "Not found", "There is no such evaluation.")


def _requested_by(job: dict[str, Any], names: dict[str, str]) -> str:
    """Who started an evaluation: the key's name, or the kind of key with its id's start."""
    who = job["requested_by"]
    name = names.get(who["key_id"])
    if name:
        return name
    return f"an {who['role']} key" if who["role"] == "admin" else f"key {who['key_id'][:12]}"


def _evaluations_page(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: Admin,
    fleet: str,
    *,
    typed: dict[str, Any] | None = None,
    errors: dict[str, str] | None = None,
    request_id: str | None = None,
    done: str | None = None,
    status: int = 200,
) -> HTMLResponse:
    listed = evaluation_service.list_for_fleet(
        session, admin.principal, fleet, limit=EVALUATIONS_SHOWN, cursor=None
    )  # may 403
    jobs = listed["items"]
    names = console_service.key_names(session, [j["requested_by"]["key_id"] for j in jobs])
    return _page(
        request,
        "evaluations.html",
        admin,
        status,
        nav="evaluations",
        fleet=fleet,
        fleets=_fleet_choice(session, admin, fleet),
        jobs=jobs,
        by={j["evaluation_id"]: _requested_by(j, names) for j in jobs},
        more=listed["next_cursor"] is not None,
        active=any(views.job_active(j) for j in jobs),
        zone=console_service.time_zones(session, ctx, {fleet})[fleet],
        typed=typed or {"picks": [], "other": "", "since": "", "until": "", "estimator": ""},
        errors=errors or {},
        request_id=request_id or secrets.token_hex(16),
        choices=views.WHAT_IF_CHOICES,
        estimators=ESTIMATORS,
        max_candidates=evaluation_service.MAX_CANDIDATES,
        done=done,
        form_status=status,
        action=console_url(request, _fleet_url("/evaluations", fleet)),
        here=console_url(request, _fleet_url("/evaluations", fleet)),
    )


@router.get("/evaluations")
def evaluations_page(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
    done: Annotated[str | None, Query(max_length=16)] = None,
) -> HTMLResponse:
    """What if the robots used another learner: the form that starts an evaluation of
    candidate learners on the fleet's logs, and the fleet's evaluations, newest first, with
    their progress (staff: their fleet; admins: ``?fleet=``)."""
    name = fleet or admin.principal.fleet
    return _evaluations_page(
        request, session, ctx, admin, name, done="cancelled" if done == "cancelled" else None
    )


def _day(text: str, zone: str) -> dt.datetime:
    """A day typed on the form (YYYY-MM-DD) as its first moment in the fleet's time zone;
    ``ValueError`` when it is no date."""
    if not _DATE_TEXT.match(text):
        raise ValueError(text)
    return dt.datetime.combine(dt.date.fromisoformat(text), dt.time(0), zoneinfo.ZoneInfo(zone))


def _busy_words(job: dict[str, Any], names: dict[str, str], zone: str) -> str:
    state = "running" if job["status"] == "running" else "waiting to start"
    return (
        f"Another evaluation of this fleet is {state} (started "
        f"{views.fmt_zone(job['created_at'], zone)} by {_requested_by(job, names)}): one "
        "evaluation of a fleet runs at a time. Wait for it to finish, or cancel it in the list "
        "below; what you chose is kept here."
    )


@router.post("/evaluations")
def start_evaluation(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> Response:
    """Start an evaluation of the chosen learners on the fleet's logs (as POST
    /v1/admin/fleets/{fleet}/evaluations, through the same service: validated, one at a time
    per fleet, idempotent on the form's request id, audited there), then its page. A mistake,
    or another evaluation under way, comes back on the form in words, with what was chosen."""
    check_post(request, admin, form)
    name = fleet or admin.principal.fleet
    principal = admin.principal
    evaluation_service.list_for_fleet(session, principal, name, limit=1, cursor=None)  # may 403
    zone = console_service.time_zones(session, ctx, {name})[name]
    typed: dict[str, Any] = {
        "picks": [key for field, key, _ in views.WHAT_IF_CHOICES if form.get(field)],
        **{k: form.get(k, "").strip() for k in _FORM_TEXT},
    }
    request_id = form.get("request_id", "")
    errors: dict[str, str] = {}

    def again(status: int, *, new_id: bool = False) -> HTMLResponse:
        return _evaluations_page(
            request,
            session,
            ctx,
            admin,
            name,
            typed=typed,
            errors=errors,
            request_id=None if new_id else request_id,
            status=status,
        )

    if not _USER_ID.match(request_id):
        errors["general"] = (
            "The form is incomplete (its number is missing): reload the page and try again."
        )
        return again(400, new_id=True)
    specs: list[CandidateSpec] = [parse_candidate(key) for key in typed["picks"]]
    for line in typed["other"].splitlines():
        if not line.strip():
            continue
        try:
            specs.append(parse_candidate(line))
        except ValueError as exc:
            errors["other"] = views.sentence(str(exc))
            break
    seen: set[str] = set()
    for spec in specs:
        if spec.key in seen:
            errors["candidates"] = (
                f"{spec.label} is chosen twice: choose each learner once (among the choices, or "
                "under other learners)."
            )
        seen.add(spec.key)
    if not specs and "other" not in errors:
        errors["candidates"] = "Choose at least one learner to compare with what the robots do now."
    elif len(specs) > evaluation_service.MAX_CANDIDATES:
        errors["candidates"] = (
            f"Choose at most {evaluation_service.MAX_CANDIDATES} learners at a time "
            f"({len(specs)} are chosen)."
        )
    since = until = None
    for field in ("since", "until"):
        if not typed[field]:
            continue
        try:
            day = _day(typed[field], zone)
        except ValueError:
            errors[field] = "Write the date as year-month-day (2026-11-01), or leave it empty."
            continue
        if field == "since":
            since = day
        else:
            until = day + dt.timedelta(days=1)  # the last day counts whole
    if since is not None and until is not None and until <= since:
        errors["until"] = "The period ends before it starts: choose an end on or after its start."
    if typed["estimator"] and typed["estimator"] not in ESTIMATORS:
        errors["estimator"] = f"Choose the way of estimating among {', '.join(ESTIMATORS)}."
    if errors:
        return again(422)
    try:
        wanted = evaluation_service.asked(
            request_id,
            [{"algorithm": s.algorithm, "params": dict(s.params)} for s in specs],
            since=since,
            until=until,
            estimator=typed["estimator"] or None,
        )
    except ValidationFailed as exc:  # the form's own checks above say it first, in words
        errors["general"] = views.sentence(exc.detail)
        return again(422)
    try:
        job, _ = evaluation_service.start(
            session,
            ctx,
            principal,
            name,
            wanted,
            runner=getattr(request.app.state, "evaluations", None),
        )
    except Conflict as exc:
        if exc.detail.startswith("request_id"):
            errors["general"] = (
                "This form was already used to start another evaluation. Check the list below, "
                "then choose again."
            )
            return again(409, new_id=True)
        newest = evaluation_service.list_for_fleet(session, principal, name, limit=1, cursor=None)
        busy = [j for j in newest["items"] if views.job_active(j)]
        if busy:
            names = console_service.key_names(session, [busy[0]["requested_by"]["key_id"]])
            errors["general"] = _busy_words(busy[0], names, zone)
        else:
            errors["general"] = views.sentence(exc.detail)
        return again(409)
    except NotFound:
        errors["general"] = (
            f"Nobody in fleet {name} yet: there is nothing to evaluate until its robots have met "
            "someone."
        )
        return again(404)
    return _redirect(request, _fleet_url(f"/evaluations/{job['evaluation_id']}", name))


@router.get("/evaluations/{evaluation_id}")
@writes  # each person the result names is recorded as looked at
def evaluation_page(
    request: Request,
    evaluation_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
) -> HTMLResponse:
    """One evaluation: while it runs, its progress (the page follows it); once done, what it
    found in words, per learner, beside what the robots earn now, a plot, and per person (each
    person named is recorded as looked at)."""
    _check_evaluation_id(evaluation_id)
    name = fleet or admin.principal.fleet
    job = evaluation_service.get(
        session,
        ctx,
        admin.principal,
        name,
        evaluation_id,
        persons=not request.scope.get(HEAD_KEY),
        via="console",
    )
    result = job["result"]
    names = console_service.key_names(session, [job["requested_by"]["key_id"]])
    persons = []
    if result is not None:
        for row in result.get("persons") or []:
            words = [views.person_words(row["user_id"], c, row) for c in result["candidates"]]
            persons.append((row, words))
    return _page(
        request,
        "evaluation.html",
        admin,
        nav="evaluations",
        fleet=name,
        job=job,
        result=result,
        by=_requested_by(job, names),
        plot=views.evaluation_plot(result) if result is not None else None,
        persons=persons,
        zone=console_service.time_zones(session, ctx, {name})[name],
    )


@router.get("/evaluations/{evaluation_id}/progress")
def evaluation_progress(
    request: Request,
    evaluation_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
) -> HTMLResponse:
    """An evaluation's state and progress, as an HTML fragment its page follows while it runs
    (nobody's row: no look)."""
    _check_evaluation_id(evaluation_id)
    name = fleet or admin.principal.fleet
    job = evaluation_service.get(
        session, ctx, admin.principal, name, evaluation_id, persons=False, via="console"
    )
    zone = console_service.time_zones(session, ctx, {name})[name]
    return _page(request, "_evaluation_status.html", admin, fleet=name, job=job, zone=zone)


@router.post("/evaluations/{evaluation_id}/cancel")
def cancel_evaluation(
    request: Request,
    evaluation_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> RedirectResponse:
    """Cancel an evaluation (as POST .../evaluations/{id}/cancel: audited there), then back to
    the list or to the evaluation's page, whichever the button was on."""
    _check_evaluation_id(evaluation_id)
    check_post(request, admin, form)
    name = fleet or admin.principal.fleet
    evaluation_service.cancel(session, ctx, admin.principal, name, evaluation_id)
    if form.get("back") == "list":
        return _redirect(request, _fleet_url("/evaluations", name, done="cancelled"))
    return _redirect(request, _fleet_url(f"/evaluations/{evaluation_id}", name))


@router.get("/users/{user_id}/whatif")
@writes  # the person's row of an evaluation is recorded as looked at
def whatif_page(
    request: Request,
    user_id: str,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
) -> HTMLResponse:
    """What the newest finished evaluation of the fleet found for this person, from their own
    episodes, in words (recorded as a look at the person); nothing when none names them."""
    _check_user_id(user_id)
    principal = admin.principal
    user = users_service.get_user(session, principal, user_id, fleet=fleet)
    looked = _looked(request, session, admin, user, None)  # the row's look is recorded below
    found = None
    if not request.scope.get(HEAD_KEY):
        found = evaluation_service.person_rows(session, ctx, principal, user.fleet, user_id)
    mission = console_service.user_mission(session, ctx, user)
    who = user.display_name or user.user_id
    job = row = None
    words: list[tuple[dict[str, Any], views.PersonWords]] = []
    if found is not None:
        job, row = found
        words = [(c, views.person_words(who, c, row)) for c in job["result"]["candidates"]]
    return _page(
        request,
        "whatif.html",
        admin,
        looked=looked,
        user=user,
        tab="whatif",
        job=job,
        row=row,
        words=words,
        mission=mission,
        zone=mission.time_zone,
        counts=_counts(session, user),
        history_from=console_service.history_from(session, user),
    )


# -- rollout: try a learner without acting (a shadow), then on some of the people (a canary) ---
_PERCENT_TEXT = re.compile(r"^([0-9]{1,3}(?:[.,][0-9]{1,2})?)\s*%?$")
_LEARNER_FIELDS = ("learner", "other", "percent")
_SHADOW_DEFAULT = {"learner": "", "other": "", "percent": "100"}
_ROLLOUT_DEFAULT = {"learner": "", "other": "", "percent": "20"}
_REASON_MAX = 500


def _latest(read: Callable[..., dict[str, Any]], *args: Any) -> dict[str, Any] | None:
    """The fleet's newest shadow or rollout as the service gives it (may 403), or None when the
    fleet never had one."""
    try:
        return read(*args)
    except NotFound:
        return None


def _mover(request: Request) -> rollouts_service.Mover | None:
    """The worker's mover of people between learners: a rollout's moves are done in the
    background, a person at a time, once the change is committed (as the API's routes do)."""
    mover: rollouts_service.Mover | None = getattr(request.app.state, "rollout_mover", None)
    return mover


def _chosen(typed: dict[str, str], errors: dict[str, str]) -> CandidateSpec | None:
    """The learner chosen on a form: one of the What if form's choices, or another typed as
    ``attune evaluate --candidate`` reads it; a mistake goes to ``errors`` in words."""
    choice = typed["learner"]
    keys = {key for _, key, _ in views.CANDIDATE_CHOICES}
    if choice == "other":
        if not typed["other"]:
            errors["learner"] = (
                "Write the other learner, such as hri:tau=0.02, or choose one of the list."
            )
            return None
        try:
            return parse_candidate(typed["other"])
        except ValueError as exc:
            errors["learner"] = views.sentence(str(exc))
            return None
    if choice not in keys:
        errors["learner"] = "Choose the learner to try."
        return None
    return parse_candidate(choice)


def _share(text: str, errors: dict[str, str]) -> float | None:
    """A percentage typed on a form (``20``, ``12.5``, ``20 %``) as a share above 0, at most 1;
    a mistake goes to ``errors`` in words."""
    found = _PERCENT_TEXT.match(text.strip())
    value = float(found.group(1).replace(",", ".")) if found else None
    if value is None or not 0.0 < value <= 100.0:
        errors["percent"] = (
            "Write the percentage of people as a number above 0 and at most 100, such as 20."
        )
        return None
    return value / 100.0


def _rollout_page(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: Admin,
    fleet: str,
    *,
    which: str | None = None,
    typed: dict[str, str] | None = None,
    errors: dict[str, str] | None = None,
    done: str | None = None,
    moved: int | None = None,
    status: int = 200,
) -> HTMLResponse:
    principal = admin.principal
    rollout = _latest(rollouts_service.rollout_view, session, ctx, principal, fleet)  # may 403
    shadow = _latest(shadows_service.shadow_view, session, ctx, principal, fleet)
    names = console_service.key_names(
        session,
        [
            k
            for found in (rollout, shadow)
            if found is not None
            for k in (found["started_by"], found.get("ended_by"), found.get("stopped_by"))
            if k
        ],
    )
    running = rollout is not None and rollout["status"] == "running"
    forms = {
        "shadow": dict(_SHADOW_DEFAULT),
        "rollout": dict(_ROLLOUT_DEFAULT),
        "share": {"percent": views.percent_field(rollout["share"]) if rollout else ""},
    }
    if which is not None and typed is not None:
        forms[which] = typed
    return _page(
        request,
        "rollout.html",
        admin,
        status,
        nav="rollout",
        fleet=fleet,
        fleets=_fleet_choice(session, admin, fleet),
        shadow=shadow,
        rollout=rollout,
        running=running,
        plot=views.rollout_plot(rollout["comparison"]) if rollout else None,
        names=names,
        zone=console_service.time_zones(session, ctx, {fleet})[fleet],
        choices=views.CANDIDATE_CHOICES,
        forms=forms,
        which=which,
        errors=errors or {},
        form_status=status,
        done=done if done in views.ROLLOUT_DONE else None,
        moved=moved,
        here=console_url(request, _fleet_url("/rollout", fleet)),
    )


@router.get("/rollout")
def rollout_page(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
    done: Annotated[str | None, Query(max_length=16)] = None,
    moved: Annotated[int | None, Query(ge=0, le=1_000_000_000)] = None,
) -> HTMLResponse:
    """Trying another learner safely: first beside the robots without acting (a shadow: how
    often it would have done what they did, and what it would likely earn), then on a
    percentage of the people (a rollout: the two groups compared while it runs, promoted or
    rolled back), in words (staff: their fleet; admins: ``?fleet=``)."""
    name = fleet or admin.principal.fleet
    return _rollout_page(request, session, ctx, admin, name, done=done, moved=moved)


def _typed(form: dict[str, str]) -> dict[str, str]:
    return {k: form.get(k, "").strip() for k in _LEARNER_FIELDS}


@router.post("/rollout/shadow")
def start_shadow(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> Response:
    """Start a shadow of the chosen learner over a percentage of the fleet's people (as PUT
    /v1/admin/fleets/{fleet}/shadow, through the same service: audited there), then back to the
    page. A mistake, or a shadow already running, comes back on the form in words."""
    check_post(request, admin, form)
    name = fleet or admin.principal.fleet
    principal = admin.principal
    running = _latest(shadows_service.shadow_view, session, ctx, principal, name)  # may 403
    typed = _typed(form)
    errors: dict[str, str] = {}

    def again(status: int) -> HTMLResponse:
        return _rollout_page(
            request,
            session,
            ctx,
            admin,
            name,
            which="shadow",
            typed=typed,
            errors=errors,
            status=status,
        )

    spec = _chosen(typed, errors)
    share = _share(typed["percent"], errors)
    if spec is None or share is None:
        return again(422)
    if running is not None and running["status"] == "running":
        errors["general"] = (
            f"A shadow of {running['candidate']['label']} is already running in this fleet: "
            "stop it before trying another learner without acting."
        )
        return again(409)
    try:
        _, started = shadows_service.put_shadow(
            session,
            ctx,
            principal,
            name,
            algorithm=spec.algorithm,
            params=dict(spec.params),
            share=share,
        )
    except ValidationFailed as exc:  # the form's own checks above say it first, in words
        errors["general"] = views.sentence(exc.detail)
        return again(422)
    except Conflict as exc:
        errors["general"] = views.sentence(exc.detail)
        return again(409)
    if not started:  # one started meanwhile: change nothing
        raise Conflict("A shadow started in this fleet meanwhile: reload the page to see it.")
    return _redirect(request, _fleet_url("/rollout", name, done="shadow-started"))


def _running_shadow(
    session: RequestSession, ctx: ServiceContext, admin: Admin, fleet: str
) -> dict[str, Any]:
    shadow = _latest(shadows_service.shadow_view, session, ctx, admin.principal, fleet)
    if shadow is None or shadow["status"] != "running":
        raise PageError(
            409, "Conflict", f"No shadow is running in fleet {fleet}: there is nothing to stop."
        )
    return shadow


def _rollout_confirm(
    request: Request,
    admin: Admin,
    fleet: str,
    *,
    action: str,
    title: str,
    text: str,
    button: str,
    hidden: dict[str, str],
    reason: str | None = None,
    error: str | None = None,
    status: int = 200,
) -> HTMLResponse:
    return _page(
        request,
        "rollout_confirm.html",
        admin,
        status,
        nav="rollout",
        fleet=fleet,
        action=action,
        title=title,
        text=text,
        button=button,
        hidden=hidden,
        reason=reason,
        reason_max=_REASON_MAX,
        error=error,
        form_status=status,
        post=console_url(request, _fleet_url(f"/rollout/{action}", fleet)),
        back=console_url(request, _fleet_url("/rollout", fleet)),
    )


def _stop_words(shadow: dict[str, Any]) -> tuple[str, str, str]:
    label = shadow["candidate"]["label"]
    return (
        f"Stop trying {label} without acting",
        f"{label} stops deciding beside the robots. What it decided so far, and what it would "
        "have earned, stay on the page. Nothing changes for anyone: it never acted.",
        f"Yes, stop trying {label}",
    )


@router.get("/rollout/shadow/stop")
def stop_shadow_confirm(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
) -> HTMLResponse:
    """Ask before stopping the fleet's shadow."""
    name = fleet or admin.principal.fleet
    shadow = _running_shadow(session, ctx, admin, name)
    title, text, button = _stop_words(shadow)
    return _rollout_confirm(
        request,
        admin,
        name,
        action="shadow/stop",
        title=title,
        text=text,
        button=button,
        hidden={"shadow_id": shadow["shadow_id"]},
    )


@router.post("/rollout/shadow/stop")
def stop_shadow(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> RedirectResponse:
    """Stop the fleet's shadow (as DELETE /v1/admin/fleets/{fleet}/shadow: audited there), the
    one the confirmation named, then back to the page."""
    check_post(request, admin, form)
    name = fleet or admin.principal.fleet
    shadow = _running_shadow(session, ctx, admin, name)
    if form.get("shadow_id") != shadow["shadow_id"]:
        raise PageError(
            409,
            "Conflict",
            "The shadow this confirmation was about has ended meanwhile, and another one runs: "
            "go back to the rollout page to see it.",
        )
    shadows_service.stop_shadow(session, ctx, admin.principal, name)
    return _redirect(request, _fleet_url("/rollout", name, done="shadow-stopped"))


@router.post("/rollout")
def start_rollout(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> Response:
    """Roll the chosen learner out to a percentage of the fleet's people (as PUT
    /v1/admin/fleets/{fleet}/rollout, through the same service: the people moved keep what was
    learned, audited there), then back to the page. A mistake, or a rollout already running,
    comes back on the form in words."""
    check_post(request, admin, form)
    name = fleet or admin.principal.fleet
    principal = admin.principal
    current = _latest(rollouts_service.rollout_view, session, ctx, principal, name)  # may 403
    typed = _typed(form)
    errors: dict[str, str] = {}

    def again(status: int) -> HTMLResponse:
        return _rollout_page(
            request,
            session,
            ctx,
            admin,
            name,
            which="rollout",
            typed=typed,
            errors=errors,
            status=status,
        )

    spec = _chosen(typed, errors)
    share = _share(typed["percent"], errors)
    if spec is None or share is None:
        return again(422)
    if current is not None and current["status"] == "running":
        errors["general"] = (
            f"A rollout of {current['candidate']['label']} is already running in this fleet: "
            "promote it or roll it back before rolling out another learner."
        )
        return again(409)
    try:
        _, started = rollouts_service.put_rollout(
            session,
            ctx,
            principal,
            name,
            algorithm=spec.algorithm,
            params=dict(spec.params),
            share=share,
            mover=_mover(request),
        )
    except ValidationFailed as exc:  # the form's own checks above say it first, in words
        errors["general"] = views.sentence(exc.detail)
        return again(422)
    except Conflict as exc:
        errors["general"] = views.sentence(exc.detail)
        return again(409)
    if not started:  # one started meanwhile: change nothing
        raise Conflict("A rollout started in this fleet meanwhile: reload the page to see it.")
    return _redirect(request, _fleet_url("/rollout", name, done="started"))


def _running_rollout(
    session: RequestSession, ctx: ServiceContext, admin: Admin, fleet: str, what: str
) -> dict[str, Any]:
    rollout = _latest(rollouts_service.rollout_view, session, ctx, admin.principal, fleet)
    if rollout is None or rollout["status"] != "running":
        raise PageError(
            409, "Conflict", f"No rollout is running in fleet {fleet}: there is nothing to {what}."
        )
    return rollout


def _same_rollout(form: dict[str, str], rollout: dict[str, Any]) -> None:
    if form.get("rollout_id") != rollout["rollout_id"]:
        raise PageError(
            409,
            "Conflict",
            "The rollout this form was about has ended meanwhile, and another one runs: go back "
            "to the rollout page to see it.",
        )


@router.post("/rollout/share")
def change_rollout_share(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> Response:
    """Change the percentage of people of the running rollout (as PUT .../rollout with its own
    learner: a higher one moves more people now, a lower one moves nobody; audited there), then
    back to the page. A mistake comes back on the form in words."""
    check_post(request, admin, form)
    name = fleet or admin.principal.fleet
    rollout = _running_rollout(session, ctx, admin, name, "change")
    _same_rollout(form, rollout)
    typed = {"percent": form.get("percent", "").strip()}
    errors: dict[str, str] = {}
    share = _share(typed["percent"], errors)
    if share is None:
        return _rollout_page(
            request,
            session,
            ctx,
            admin,
            name,
            which="share",
            typed=typed,
            errors=errors,
            status=422,
        )
    candidate = rollout["candidate"]
    after, started = rollouts_service.put_rollout(
        session,
        ctx,
        admin.principal,
        name,
        algorithm=candidate["algorithm"],
        params=dict(candidate["params"]),
        share=share,
        mover=_mover(request),
    )
    if started:  # it ended meanwhile: start nothing
        raise Conflict("The rollout ended meanwhile: reload the page to see it.")
    moved = after["people"]["candidate"] - rollout["people"]["candidate"]
    return _redirect(request, _fleet_url("/rollout", name, done="share", moved=max(0, moved)))


def _promote_words(rollout: dict[str, Any], fleet: str) -> tuple[str, str, str]:
    label = rollout["candidate"]["label"]
    control = rollout["people"]["control"]
    return (
        f"Promote {label}",
        f"Give {label} to everyone of the rollout in fleet {fleet}: the "
        f"{views.people_words(control)} who keep the current learner move to {label} now, "
        f"keeping what the robots learned with them, and everyone the robots meet for the first "
        f"time from now on starts with {label}. The rollout ends.",
        f"Yes, promote {label}",
    )


def _rollback_words(rollout: dict[str, Any], fleet: str) -> tuple[str, str, str]:
    label = rollout["candidate"]["label"]
    served = rollout["people"]["candidate"]
    return (
        f"Roll back {label}",
        f"Give the {views.people_words(served)} served by {label} in fleet {fleet} the learner "
        f"they had before, taught everything they did meanwhile (what {label} learned with them "
        "is not lost), and let everyone the robots meet for the first time start with the "
        "fleet's usual learner again. The rollout ends.",
        f"Yes, roll back {label}",
    )


@router.get("/rollout/promote")
def promote_confirm(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
) -> HTMLResponse:
    """Ask before promoting the fleet's rollout."""
    name = fleet or admin.principal.fleet
    rollout = _running_rollout(session, ctx, admin, name, "promote")
    title, text, button = _promote_words(rollout, name)
    return _rollout_confirm(
        request,
        admin,
        name,
        action="promote",
        title=title,
        text=text,
        button=button,
        hidden={"rollout_id": rollout["rollout_id"]},
    )


@router.post("/rollout/promote")
def promote_rollout(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> RedirectResponse:
    """Promote the rollout the confirmation named (as POST .../rollout/promote: audited
    there), then back to the page."""
    check_post(request, admin, form)
    name = fleet or admin.principal.fleet
    rollout = _running_rollout(session, ctx, admin, name, "promote")
    _same_rollout(form, rollout)
    rollouts_service.promote(session, ctx, admin.principal, name, mover=_mover(request))
    return _redirect(request, _fleet_url("/rollout", name, done="promoted"))


@router.get("/rollout/rollback")
def rollback_confirm(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    fleet: FleetQuery = None,
) -> HTMLResponse:
    """Ask before rolling the fleet's rollout back, with room for why."""
    name = fleet or admin.principal.fleet
    rollout = _running_rollout(session, ctx, admin, name, "roll back")
    title, text, button = _rollback_words(rollout, name)
    return _rollout_confirm(
        request,
        admin,
        name,
        action="rollback",
        title=title,
        text=text,
        button=button,
        hidden={"rollout_id": rollout["rollout_id"]},
        reason="",
    )


@router.post("/rollout/rollback")
def roll_back_rollout(
    request: Request,
    session: RequestSession,
    ctx: ServiceContext,
    admin: AdminDep,
    form: FormDep,
    fleet: FleetQuery = None,
) -> Response:
    """Roll back the rollout the confirmation named, with the reason given if any (as POST
    .../rollout/rollback: audited there), then back to the page. A reason too long comes back
    on the confirmation in words."""
    check_post(request, admin, form)
    name = fleet or admin.principal.fleet
    rollout = _running_rollout(session, ctx, admin, name, "roll back")
    _same_rollout(form, rollout)
    reason = form.get("reason", "").strip()
    if len(reason) > _REASON_MAX:
        title, text, button = _rollback_words(rollout, name)
        return _rollout_confirm(
            request,
            admin,
            name,
            action="rollback",
            title=title,
            text=text,
            button=button,
            hidden={"rollout_id": rollout["rollout_id"]},
            reason=reason,
            error=(
                f"Say why in at most {_REASON_MAX} characters ({len(reason):,} are written); "
                "nothing was rolled back."
            ),
            status=422,
        )
    rollouts_service.roll_back(
        session, ctx, admin.principal, name, reason=reason or None, mover=_mover(request)
    )
    return _redirect(request, _fleet_url("/rollout", name, done="rolled-back"))


@router.get("/{rest:path}")
def not_found(request: Request, rest: str) -> RedirectResponse:
    """Any other console address: the users list for ``/admin/``, else a 404 page."""
    if not rest:
        return home(request)
    raise PageError(404, "Not found", "There is no such console page.")
