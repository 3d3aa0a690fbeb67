"""API fuzzing: schemathesis against the live OpenAPI schema of a real ``attune serve``.

Every operation gets generated requests (valid and invalid) with a valid admin key; a stateful
run follows the schema's links as a robot would (create a user, start an episode, report the
outcomes of its decisions). No response may be a 5xx, every response must conform to the
schema, and every error must be the contract's one body ``{"error", "detail", "request_id"}``.
The run is bounded: a fixed number of examples per operation and of stateful steps.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterator
from typing import Any

import httpx
import hypothesis
import hypothesis.errors
import pytest
import schemathesis
from schemathesis import Case, GenerationMode
from schemathesis.core.result import Ok
from schemathesis.specs.openapi.schemas import OpenApiSchema
from sqlalchemy import create_engine

from app.db import migrate
from app.db.base import Base
from app.learning import office_mission
from app.main import create_app
from app.services.context import LearnerCache
from app.settings import Settings
from tests.support.live import LiveService, fresh_database, make_keys, serving

pytestmark = pytest.mark.live

SETTINGS = hypothesis.settings(
    max_examples=40,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=list(hypothesis.HealthCheck),
)
# A schema cannot say which strings the mission accepts (situations, services) or which ids
# exist, so valid-by-schema data may rightly get 404/409/422: that check is not ours to pass.
EXCLUDED = ["positive_data_acceptance"]
MISSION = office_mission()
SITUATIONS = MISSION.situations
ANSWERS: dict[str, list[dict[str, Any]]] = {  # two valid answers per kind of decision
    "initiate": [{"response": "accepted"}, {"response": "rejected"}],
    "pass": [{"response": "none"}, {"response": "human_request", "service": "ProvideDrink"}],
    "query_type": [{"response": "answered", "service": "ProvideDrink"}, {"response": "terminated"}],
    "query_detail": [{"response": "answered"}, {"response": "terminated"}],
    "perform": [{"response": "accepted"}, {"response": "rejected"}],
}


@schemathesis.check
def contract_error_body(ctx: Any, response: Any, case: Case[Any]) -> bool | None:
    """Every error is ``{"error": <name>, "detail": <sentence>, "request_id": <its
    X-Request-ID>}`` (plus ``fields`` on 422)."""
    if response.status_code < 400:
        return None
    body = json.loads(response.content)
    assert isinstance(body, dict), body
    assert set(body) <= {"error", "detail", "fields", "request_id"}, body
    assert body.get("request_id") == response.headers.get("x-request-id", [None])[0], body
    assert isinstance(body.get("error"), str), body
    assert isinstance(body.get("detail"), str), body
    assert body["detail"], body
    if response.status_code in (429, 503):
        assert response.headers.get("retry-after", [""])[0].isdigit(), response.headers
    return True


@pytest.fixture(scope="module")
def live() -> Iterator[tuple[LiveService, dict[str, str]]]:
    with fresh_database("sqlite") as url, LiveService(url) as service:
        keys = {"admin": make_keys(url, 1, "admin")[0], "robot": make_keys(url, 1)[0]}
        yield service, keys


@pytest.fixture(scope="module")
def api_schema(live: tuple[LiveService, dict[str, str]]) -> OpenApiSchema:
    service, _ = live
    return schemathesis.openapi.from_url(f"{service.url}/openapi.json")


def _excluded() -> list[Any]:
    from schemathesis.checks import CHECKS

    return [c for c in CHECKS.get_all() if getattr(c, "__name__", "") in EXCLUDED]


@pytest.mark.parametrize("mode", [GenerationMode.POSITIVE, GenerationMode.NEGATIVE])
def test_every_operation(
    api_schema: OpenApiSchema, live: tuple[LiveService, dict[str, str]], mode: GenerationMode
) -> None:
    """Generated requests to every operation, with a valid admin key."""
    _, keys = live
    headers = {"Authorization": f"Bearer {keys['admin']}"}
    excluded = _excluded()
    failures: dict[str, str] = {}
    labels = []
    for result in api_schema.get_all_operations():
        assert isinstance(result, Ok), result
        operation = result.ok()
        labels.append(operation.label)

        @hypothesis.given(case=operation.as_strategy(generation_mode=mode))
        @SETTINGS
        def fuzz(case: Case[Any]) -> None:
            case.call_and_validate(
                headers=headers, additional_checks=[contract_error_body], excluded_checks=excluded
            )

        try:
            fuzz()
        except hypothesis.errors.Unsatisfiable:
            # No parameters and no body: there is no invalid request to make (probes, mission).
            assert mode is GenerationMode.NEGATIVE, operation.label
        except Exception as exc:  # every operation is tried; all failures are reported
            failures[operation.label] = f"{type(exc).__name__}: {exc}"[:3000]
    assert len(labels) >= 15, labels
    assert failures == {}, "\n\n".join(f"{k}:\n{v}" for k, v in failures.items())


@pytest.fixture
def fresh_app() -> Iterator[tuple[str, str, Any]]:
    """The service on a fresh SQLite database, served over HTTP from this process (so that each
    stateful scenario can start from empty tables and an empty learner cache)."""
    with fresh_database("sqlite") as url:
        migrate.upgrade(url)
        app = create_app(Settings(database_url=url, _env_file=None))  # type: ignore[call-arg]
        key = make_keys(url, 1)[0]
        try:
            with serving(app) as base_url:
                yield base_url, key, app
        finally:
            app.state.db.dispose()


def test_stateful_robot_flows(fresh_app: tuple[str, str, Any]) -> None:
    """Scenarios that follow the schema's links with a robot key: create a user, start an
    episode, report the outcomes of its decisions, read the trace and the model."""
    base_url, key, app = fresh_app
    # A robot key may not call the deployment admin's routes: those calls would only spend the
    # scenarios' budget on 403s, so the robot's flows leave them out.
    api_schema = schemathesis.openapi.from_url(f"{base_url}/openapi.json").exclude(
        path_regex="^/v1/admin/"
    )
    headers = {"Authorization": f"Bearer {key}"}
    excluded = _excluded()
    seen: Counter[tuple[str, int]] = Counter()
    decisions: dict[str, dict[str, Any]] = {}  # decision id -> its action, as the robot saw it
    engine = create_engine(app.state.settings.database_url)

    class RobotFlows(api_schema.as_state_machine()):  # type: ignore[misc]
        def setup(self) -> None:
            # Every scenario starts from the same empty service (keys kept): the same choices
            # must meet the same answers, or the scenarios could not be generated reliably.
            # (A robot key leaves no audit entries, and the audit log refuses deletes.)
            with engine.begin() as conn:
                for table in reversed(Base.metadata.sorted_tables):
                    if table.name not in ("api_keys", "audit_log"):
                        conn.execute(table.delete())
            app.state.ctx.cache = LearnerCache(app.state.settings.model_cache_size)

        def get_call_kwargs(self, case: Case[Any]) -> dict[str, Any]:
            return {"headers": headers}

        def before_call(self, case: Case[Any]) -> None:
            # The schema cannot name the mission's situations or say which response a
            # decision expects; map the generated values onto them so that flows get deep.
            if isinstance(case.query, dict):
                case.query.pop("fleet", None)  # a robot's key names its fleet; naming one is 403
            body = case.body
            negative = (
                case.meta is not None and case.meta.generation.mode is GenerationMode.NEGATIVE
            )
            if negative or not isinstance(body, dict):
                return  # invalid requests stay invalid
            pick = sum(json.dumps(body, sort_keys=True, default=str).encode())
            if case.operation.label == "POST /v1/users/{user_id}/episodes":
                body.update(
                    situation=SITUATIONS[pick % len(SITUATIONS)],
                    occurred_at="2026-11-22T15:10:00+08:00",
                    initiator="robot",
                    request=None,
                )
            elif case.operation.label == "POST /v1/episodes/{episode_id}/outcomes":
                action = decisions.get(str(body.get("decision_id")), {"kind": "initiate"})
                body.update({"service": None, "detail": None, **ANSWERS[action["kind"]][pick % 2]})
                if action["kind"] == "query_detail":
                    body["detail"] = MISSION.service(action["service"]).details[0]

        def after_call(self, response: Any, case: Case[Any]) -> None:
            seen[(case.operation.label, response.status_code)] += 1
            try:
                decision = response.json().get("decision")
            except ValueError:
                return
            if isinstance(decision, dict) and "decision_id" in decision:
                decisions[decision["decision_id"]] = decision["action"]

        def validate_response(
            self, response: Any, case: Case[Any], additional_checks: Any = None, **kwargs: Any
        ) -> None:
            case.validate_response(
                response,
                additional_checks=[contract_error_body],
                excluded_checks=excluded,
                headers=headers,
            )

    try:
        RobotFlows.run(
            settings=hypothesis.settings(
                max_examples=100,
                stateful_step_count=8,
                deadline=None,
                derandomize=True,
                database=None,
                suppress_health_check=list(hypothesis.HealthCheck),
                phases=[hypothesis.Phase.generate],
            )
        )  # bounded: a failure is reported unshrunk
    finally:
        engine.dispose()
    # The scenarios got past the user: episodes were started on users they had created. (How
    # far each scenario follows the links after that is the generator's choice; that the links
    # lead from a user to an outcome is checked on its own below.)
    assert seen[("POST /v1/users/{user_id}/episodes", 201)] > 0, seen


def _resolve(expression: str, request_path: dict[str, str], response: dict[str, Any]) -> Any:
    """An OpenAPI runtime expression of the two forms the schema uses."""
    if expression.startswith("$request.path."):
        return request_path[expression.removeprefix("$request.path.")]
    assert expression.startswith("$response.body#/"), expression
    value: Any = response
    for part in expression.removeprefix("$response.body#/").split("/"):
        value = value[part]
    return value


def test_the_links_lead_from_a_user_to_the_episode_s_end(
    fresh_app: tuple[str, str, Any],
) -> None:
    """Following the schema's own links, and only them, from a created user: StartEpisode, then
    ReportOutcome and ReportNextOutcome until the episode ends; every call answers as its
    operation documents, and the episode's trace (GetEpisode) holds every step."""
    base_url, key, _ = fresh_app
    schema = httpx.get(f"{base_url}/openapi.json").json()
    operations = {
        op["operationId"]: (method.upper(), path, op)
        for path, item in schema["paths"].items()
        for method, op in item.items()
    }

    def links(operation_id: str, status: int) -> dict[str, Any]:
        return dict(operations[operation_id][2]["responses"][str(status)].get("links", {}))

    def follow(
        link: dict[str, Any], path: dict[str, str], answer: dict[str, Any], body: Any
    ) -> tuple[dict[str, str], httpx.Response]:
        method, template, _ = operations[link["operationId"]]
        params = {k: _resolve(v, path, answer) for k, v in link.get("parameters", {}).items()}
        if isinstance(body, dict):
            body = {
                **body,
                **{k: _resolve(v, path, answer) for k, v in link.get("requestBody", {}).items()},
            }
        url = base_url + template.format(**params)
        return params, client.request(method, url, json=body)

    with httpx.Client(headers={"Authorization": f"Bearer {key}"}, timeout=10) as client:
        created = client.put(f"{base_url}/v1/users/lin", json={"display_name": "Lin"})
        assert created.status_code == 201, created.text
        start = links("put_user", 201)["StartEpisode"]
        event = {
            "event_id": "e-1",
            "situation": SITUATIONS[0],
            "occurred_at": "2026-11-22T15:10:00+08:00",
            "initiator": "robot",
        }
        path, started = follow(start, {"user_id": "lin"}, created.json(), event)
        assert started.status_code == 201, started.text
        answer, link, steps = started.json(), links("start_episode", 201)["ReportOutcome"], 1
        while answer.get("decision") is not None:
            kind = answer["decision"]["action"]["kind"]
            reply = {"decision_id": None, **ANSWERS[kind][0]}
            if kind == "query_detail":
                reply["detail"] = MISSION.service(answer["decision"]["action"]["service"]).details[
                    0
                ]
            path, reported = follow(link, path, answer, reply)
            assert reported.status_code == 200, reported.text
            answer, link, steps = (
                reported.json(),
                links("report_outcome", 200)["ReportNextOutcome"],
                steps + 1,
            )
            assert steps < 20, "the episode should end"
        assert answer["episode"]["status"] == "closed", answer
        _, trace = follow(links("report_outcome", 200)["GetEpisode"], path, answer, None)
        assert trace.status_code == 200, trace.text
        assert trace.json()["episode_id"] == path["episode_id"]
