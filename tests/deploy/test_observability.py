"""What an operator loads: deploy/prometheus/rules.yml (checked and unit-tested by Prometheus's
own promtool) and deploy/grafana/attune.json, against the metrics the service really exports,
scraped from /metrics after traffic (in-process here; from the metrics port of a live
``attune serve --workers 2`` in the live test). docs/operations.md lists the same metrics.

promtool is Debian's (``apt-get install prometheus``; ``.ci/run`` installs it when it is
missing): without it these tests fail, they never skip."""

from __future__ import annotations

import json
import re
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml
from fastapi import FastAPI
from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families

from tests.support import people
from tests.support.episodes import event
from tests.support.fixtures import MakeKey
from tests.support.live import LiveService, free_port, fresh_database, make_keys

ROOT = Path(__file__).resolve().parents[2]
RULES = ROOT / "deploy" / "prometheus" / "rules.yml"
RULES_TEST = ROOT / "deploy" / "prometheus" / "rules_test.yml"
DASHBOARD = ROOT / "deploy" / "grafana" / "attune.json"
OPERATIONS = ROOT / "docs" / "operations.md"
PROMTOOL = "/usr/bin/promtool"
FROM_PROMETHEUS = {"up"}  # what Prometheus itself records about a scrape
TOKEN = "a-metrics-token-for-the-live-test"

_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')
_NAME = re.compile(r"[A-Za-z_:][A-Za-z0-9_:]*")


@pytest.fixture(scope="module")
def promtool() -> str:
    if not Path(PROMTOOL).exists():
        pytest.fail(
            f"{PROMTOOL} is missing: install Debian's prometheus package "
            "(apt-get install prometheus; .ci/run does it).",
            pytrace=False,
        )
    return PROMTOOL


def _rules() -> list[dict[str, Any]]:
    doc = yaml.safe_load(RULES.read_text())
    return [rule for group in doc["groups"] for rule in group["rules"]]


def _dashboard_exprs() -> list[str]:
    doc = json.loads(DASHBOARD.read_text())
    exprs = [t["expr"] for p in doc["panels"] for t in p.get("targets", [])]
    for variable in doc["templating"]["list"]:
        definition = variable.get("definition", "")
        if definition.startswith("label_values("):  # label_values(metric, label)
            exprs.append(definition.removeprefix("label_values(").split(",")[0])
    return exprs


def _names(expr: str) -> set[str]:
    """The series names a PromQL expression reads (not functions, labels or keywords)."""
    bare = _STRING.sub('""', expr)
    bare = re.sub(r"\{[^}]*\}", "", bare)  # label matchers
    bare = re.sub(r"\[[^\]]*\]", "", bare)  # ranges
    bare = re.sub(r"\b(by|without|on|ignoring|group_left|group_right)\s*\([^)]*\)", "", bare)
    words = set(_NAME.findall(bare))
    return {w for w in words if w.startswith("attune_") or ":" in w or w in FROM_PROMETHEUS}


def _named() -> dict[str, set[str]]:
    """Every series the dashboard and the alerts read, with where."""
    where: dict[str, set[str]] = {}
    for expr in _dashboard_exprs():
        for name in _names(expr):
            where.setdefault(name, set()).add("dashboard")
    for rule in _rules():
        for name in _names(rule["expr"]):
            where.setdefault(name, set()).add(rule.get("alert") or rule["record"])
    return where


def _exported(text: str) -> set[str]:
    """The series names a scrape offers: each family's samples, also for a family that has
    none yet (a labelled counter before its first label)."""
    names: set[str] = set()
    suffixes = {"counter": ("_total",), "histogram": ("_bucket", "_sum", "_count"), "gauge": ("",)}
    for family in text_string_to_metric_families(text):
        names.update(sample.name for sample in family.samples)
        names.update(family.name + s for s in suffixes.get(family.type, ("",)))
    return names


def test_promtool_checks_the_rules(promtool: str) -> None:
    done = subprocess.run(
        [promtool, "check", "rules", str(RULES)], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "SUCCESS" in done.stdout


def test_the_alerts_fire_when_they_should(promtool: str) -> None:
    """deploy/prometheus/rules_test.yml: each alert on a history that should page, and not on
    one that should not (promtool's unit tests)."""
    done = subprocess.run(
        [promtool, "test", "rules", str(RULES_TEST)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=RULES_TEST.parent,
    )
    assert done.returncode == 0, done.stdout + done.stderr


def test_the_dashboard_queries_are_promql(promtool: str, tmp_path: Path) -> None:
    """promtool parses each panel's query (Grafana's variables given values)."""
    values = {"$instance": ".*", "$fleet": ".*", "$__rate_interval": "5m"}
    rules = []
    for n, expr in enumerate(_dashboard_exprs()):
        for variable, value in values.items():
            expr = expr.replace(variable, value)
        assert "$" not in expr, expr
        rules.append({"record": f"dashboard:query{n}", "expr": expr})
    check = tmp_path / "dashboard.yml"
    check.write_text(yaml.safe_dump({"groups": [{"name": "dashboard", "rules": rules}]}))
    done = subprocess.run(
        [promtool, "check", "rules", str(check)], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stdout + done.stderr


def test_every_alert_says_what_and_how_bad() -> None:
    alerts = [rule for rule in _rules() if "alert" in rule]
    assert {a["alert"] for a in alerts} >= {
        "AttuneDown",
        "AttuneServerErrors",
        "AttuneRobotWritesSlow",
        "AttuneDatabasePoolExhausted",
        "AttuneDrainingTooLong",
        "AttuneFleetAcceptanceFalling",
    }
    for alert in alerts:
        assert alert["labels"]["severity"] in {"page", "warn", "ticket"}, alert
        assert {"summary", "description"} <= set(alert["annotations"]), alert


def _traffic(robot: httpx.Client) -> None:
    """Episodes that end well and badly, so that every family has its samples."""
    for n in range(4):
        r = robot.post(f"/v1/users/u{n}/episodes", json=event(f"e{n}"))
        assert r.status_code == 201, r.text
        ep = r.json()
        decision = ep["decision"]
        for _ in range(20):
            fields = people.answer(decision["action"], need=people.TEA if n % 2 else None)
            r = robot.post(
                f"/v1/episodes/{ep['episode_id']}/outcomes",
                json={"decision_id": decision["decision_id"], **fields},
            )
            assert r.status_code == 200, r.text
            decision = r.json()["decision"]
            if decision is None:
                break


@pytest.fixture
def robot(app: FastAPI, make_key: MakeKey) -> Iterator[TestClient]:
    with TestClient(app, headers={"Authorization": f"Bearer {make_key('robot')}"}) as client:
        yield client


def _check_names(exported: set[str]) -> None:
    recorded = {rule["record"] for rule in _rules() if "record" in rule}
    missing = {
        name: sorted(where)
        for name, where in _named().items()
        if name not in exported and name not in recorded and name not in FROM_PROMETHEUS
    }
    assert missing == {}, f"named by the dashboard or the rules but not exported: {missing}"


def test_every_metric_named_is_exported(app: FastAPI, robot: TestClient) -> None:
    _traffic(robot)
    exported = _exported(robot.get("/metrics").text)
    _check_names(exported)
    assert len(_named()) > 15  # the check reads the names: it is not vacuous


def test_the_name_check_finds_a_missing_metric() -> None:
    assert _names('sum by (fleet) (rate(attune_nothing_total{kind="x"}[5m])) / up') == {
        "attune_nothing_total",
        "up",
    }
    with pytest.raises(AssertionError, match="attune_http_requests_total"):
        _check_names({"attune_outcomes_total"})


def test_the_operations_guide_lists_every_metric(app: FastAPI, robot: TestClient) -> None:
    _traffic(robot)
    families = {
        f.name
        for f in text_string_to_metric_families(robot.get("/metrics").text)
        if not f.name.endswith("_created")  # when each series began (one process only)
    }
    table = OPERATIONS.read_text()
    documented = set(re.findall(r"^\| `(attune_[a-z0-9_]+)`", table, flags=re.MULTILINE))
    documented_families = {re.sub(r"_total$", "", name) for name in documented}
    assert documented_families == families, (
        sorted(families - documented_families),
        sorted(documented_families - families),
    )


@pytest.mark.live
def test_a_metrics_port_with_a_token_serves_every_worker(tmp_path: Path) -> None:
    """``attune serve --workers 2`` with ATTUNE_METRICS_PORT and ATTUNE_METRICS_TOKEN: the
    metrics leave the service's port, need the token, sum both workers, and hold every name the
    dashboard and the alerts read (PostgreSQL: the round trips too)."""
    metrics_port = free_port()
    env = {"ATTUNE_METRICS_PORT": str(metrics_port), "ATTUNE_METRICS_TOKEN": TOKEN}
    with fresh_database("postgresql", tmp_path) as url:
        service = LiveService(url, workers=2, log_path=tmp_path / "serve.log", env=env)
        with service:
            key = make_keys(url, 1)[0]
            with httpx.Client(
                base_url=service.url, headers={"Authorization": f"Bearer {key}"}, timeout=30
            ) as robot:
                _traffic(robot)
                assert robot.get("/metrics").status_code == 404
            scrape = f"http://127.0.0.1:{metrics_port}/metrics"
            refused = httpx.get(scrape, timeout=10)
            assert refused.status_code == 401
            assert refused.headers["www-authenticate"].startswith("Bearer")
            headers = {"Authorization": f"Bearer {TOKEN}"}

            def workers() -> float:
                text = httpx.get(scrape, headers=headers, timeout=10).text
                for family in text_string_to_metric_families(text):
                    if family.name == "attune_workers":
                        return sum(s.value for s in family.samples)
                return 0.0

            for _ in range(300):  # each worker samples its figures every second
                if workers() >= 2:
                    break
                time.sleep(0.2)
            assert workers() == 2
            text = httpx.get(scrape, headers=headers, timeout=10).text
            _check_names(_exported(text))
            assert 'route="/v1/episodes/{episode_id}/outcomes"' in text
            assert "attune_db_round_trips_total" in text
