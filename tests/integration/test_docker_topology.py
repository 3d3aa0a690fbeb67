"""docker/topology.yml and the files it mounts, checked without a Docker engine: the compose
file's services and wiring, its ATTUNE_* variables against the service's settings, nginx's site
configuration under ``nginx -t`` (Debian's nginx, the instances' host names replaced by local
addresses, which nginx must resolve), PgBouncer's ini, and prometheus.yml under ``promtool check
config`` (Debian's promtool) with the alert rules it loads."""

from __future__ import annotations

import configparser
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

from app.settings import Settings
from tests.support.nginx import NGINX, SITE, Nginx

ROOT = Path(__file__).resolve().parents[2]
DOCKER = ROOT / "docker"
TOPOLOGY = DOCKER / "topology.yml"
PROMETHEUS = DOCKER / "prometheus" / "prometheus.yml"
PGBOUNCER = DOCKER / "pgbouncer" / "pgbouncer.ini"
RULES = ROOT / "deploy" / "prometheus" / "rules.yml"
PROMTOOL = "/usr/bin/promtool"
INSTANCES = ("attune-1", "attune-2")


def _defaults(value: str) -> str:
    """``${NAME:-default}`` as compose reads it when NAME is unset."""
    return re.sub(r"\$\{[A-Z_]+:-([^}]*)\}", r"\1", value)


@pytest.fixture(scope="module")
def compose() -> dict[str, Any]:
    loaded: dict[str, Any] = yaml.safe_load(TOPOLOGY.read_text())
    return loaded


def _env(service: dict[str, Any]) -> dict[str, str]:
    return {k: _defaults(str(v)) for k, v in (service.get("environment") or {}).items()}


def test_the_services_of_the_topology(compose: dict[str, Any]) -> None:
    services = compose["services"]
    assert set(services) == {
        "postgres",
        "pgbouncer",
        "migrate",
        *INSTANCES,
        "nginx",
        "prometheus",
    }
    # Only nginx (the service) and Prometheus (its UI) are published; the instances, PgBouncer
    # and PostgreSQL are reached inside the topology's network only.
    published = {name: s["ports"] for name, s in services.items() if s.get("ports")}
    assert set(published) == {"nginx", "prometheus"}
    assert [_defaults(p).split(":")[-1] for p in published["nginx"]] == ["80"]
    # The schema is migrated once, before the instances, which do not migrate themselves.
    assert services["migrate"]["command"] == ["attune", "db", "upgrade"]
    for name in INSTANCES:
        s = services[name]
        assert s["depends_on"]["migrate"]["condition"] == "service_completed_successfully"
        assert "--no-migrate" in s["command"]
        assert "readyz" in " ".join(s["healthcheck"]["test"])
        assert s["stop_grace_period"] == "40s"
    assert services["pgbouncer"]["depends_on"]["postgres"]["condition"] == "service_healthy"


def test_every_attune_variable_is_a_setting_with_a_valid_value(compose: dict[str, Any]) -> None:
    known = {f"ATTUNE_{name.upper()}" for name in Settings.model_fields}
    for name, service in compose["services"].items():
        env = {k: v for k, v in _env(service).items() if k.startswith("ATTUNE_")}
        assert set(env) <= known, (name, set(env) - known)
        if env:
            given: dict[str, Any] = {k.removeprefix("ATTUNE_").lower(): v for k, v in env.items()}
            Settings(_env_file=None, **given)  # type: ignore[call-arg]  # raises when invalid


def test_the_instances_trust_nginx_only_and_know_its_prefix(compose: dict[str, Any]) -> None:
    services = compose["services"]
    nginx_ip = services["nginx"]["networks"]["attune"]["ipv4_address"]
    site = SITE.read_text()
    [prefix] = re.findall(r"^\s*location (/[\w-]+)/ \{", site, flags=re.M)
    for name in INSTANCES:
        env = _env(services[name])
        assert env["ATTUNE_ROOT_PATH"] == prefix
        assert env["ATTUNE_FORWARDED_ALLOW_IPS"].split(",") == [nginx_ip]
        # Through PgBouncer, whose port and database are the ini's.
        url = env["ATTUNE_DATABASE_URL"]
        assert "@pgbouncer:6432/attune" in url
    assert "proxy_pass http://attune/;" in site  # the prefix stripped


def test_nginx_passes_to_both_instances(compose: dict[str, Any]) -> None:
    services = compose["services"]
    upstream = re.findall(r"^\s*server ([\w-]+):(\d+)\b", SITE.read_text(), flags=re.M)
    ports = {name: services[name]["command"] for name in INSTANCES}
    assert upstream == [(name, ports[name][ports[name].index("--port") + 1]) for name in INSTANCES]
    mounted = services["nginx"]["volumes"]
    assert any(v.startswith("./nginx/attune.conf:/etc/nginx/conf.d/") for v in mounted)


def test_the_nginx_site_passes_nginx_t(tmp_path: Path) -> None:
    assert Path(NGINX).exists(), f"Debian's nginx is needed at {NGINX} (apt-get install nginx)"
    done = Nginx(["127.0.0.1:1", "127.0.0.1:2"], tmp_path).check()
    assert done.returncode == 0, done.stderr
    assert "test is successful" in done.stderr


def test_pgbouncer_points_at_the_topology_s_postgres(compose: dict[str, Any]) -> None:
    ini = configparser.ConfigParser(inline_comment_prefixes=(";",))
    ini.read_string(PGBOUNCER.read_text())
    target = dict(part.split("=", 1) for part in ini["databases"]["attune"].split())
    assert target == {"host": "postgres", "port": "5432", "dbname": "attune"}
    assert ini["pgbouncer"]["listen_port"] == "6432"
    # Transaction pooling, as a shared PostgreSQL is fronted; the instances know it (no
    # statement prepared on the server), or their first episode would answer 500.
    assert ini["pgbouncer"]["pool_mode"] == "transaction"
    for name in INSTANCES:
        assert _env(compose["services"][name])["ATTUNE_DATABASE_POOLER"] == "transaction"
    assert "pgbouncer" in compose["services"]["pgbouncer"]["build"]["context"]


def test_prometheus_scrapes_both_instances_with_the_rules(compose: dict[str, Any]) -> None:
    config = yaml.safe_load(PROMETHEUS.read_text())
    [job] = config["scrape_configs"]
    assert job["job_name"] == "attune"  # what the rules expect
    metrics_port = {_env(compose["services"][name])["ATTUNE_METRICS_PORT"] for name in INSTANCES}
    [port] = metrics_port
    assert job["static_configs"][0]["targets"] == [f"{name}:{port}" for name in INSTANCES]
    volumes = compose["services"]["prometheus"]["volumes"]
    assert "../deploy/prometheus/rules.yml:/etc/prometheus/rules.yml:ro" in volumes
    assert config["rule_files"] == ["rules.yml"]


def test_prometheus_yml_passes_promtool(tmp_path: Path) -> None:
    assert Path(PROMTOOL).exists(), (
        f"Debian's promtool is needed at {PROMTOOL} (apt-get install prometheus)"
    )
    # As in the container: the rules beside the configuration.
    shutil.copy(PROMETHEUS, tmp_path / "prometheus.yml")
    shutil.copy(RULES, tmp_path / "rules.yml")
    done = subprocess.run(
        [PROMTOOL, "check", "config", str(tmp_path / "prometheus.yml")],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "SUCCESS" in done.stdout + done.stderr
