"""deploy/kubernetes/ against the service it deploys: the probes' paths and ports, the command
lines of the pods and of the migration Job, the settings' names and values, the labels that tie
the objects together, and the image's user, port and writable folder (docker/Dockerfile). No
cluster runs here; what a cluster would read is read and checked."""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any

import pytest
import typer
import yaml

from app.cli import app as cli
from app.main import create_app
from app.settings import Settings
from tests.integration.test_docker import DOCKERFILE, exec_form, parse

ROOT = Path(__file__).resolve().parents[2]
MANIFESTS = ROOT / "deploy" / "kubernetes"


def _documents() -> list[dict[str, Any]]:
    docs: list[dict[str, Any]] = []
    for path in sorted(MANIFESTS.glob("*.yaml")):
        if path.name == "kustomization.yaml":
            continue
        docs.extend(d for d in yaml.safe_load_all(path.read_text()) if d)
    return docs


def _one(kind: str) -> dict[str, Any]:
    found = [d for d in _documents() if d["kind"] == kind]
    assert len(found) == 1, (kind, [d["metadata"]["name"] for d in found])
    return found[0]


def _container(workload: dict[str, Any]) -> dict[str, Any]:
    containers: list[dict[str, Any]] = workload["spec"]["template"]["spec"]["containers"]
    (container,) = containers
    return container


def _settings_env() -> dict[str, str]:
    """The environment the ConfigMap and the Secret give every pod and the Job."""
    env = dict(_one("ConfigMap")["data"])
    env.update(_one("Secret")["stringData"])
    return env


def _command(argv: list[str]) -> tuple[list[str], dict[str, Any]]:
    """The names of the ``attune`` command ``argv`` runs, and its parameters, as the command line
    parses them (an unknown command or option fails)."""
    assert argv[0] == "attune", argv
    command: Any = typer.main.get_command(cli)  # typer's own click: duck-typed
    ctx = command.context_class(command, info_name="attune")
    names: list[str] = []
    args = list(argv[1:])
    while hasattr(command, "resolve_command"):  # a group: the next word names a command
        name, sub, args = command.resolve_command(ctx, args)
        assert sub is not None, argv
        names.append(str(name))
        command = sub
        ctx = command.context_class(command, info_name=name, parent=ctx)
    params = command.make_context(names[-1], args, parent=ctx.parent).params
    return names, dict(params)


@pytest.fixture(scope="module")
def routes() -> set[str]:
    app = create_app(Settings(database_url="sqlite:///unused.db", _env_file=None))  # type: ignore[call-arg]
    try:
        return set(app.openapi()["paths"])
    finally:
        app.state.db.dispose()


def test_kustomization_lists_every_manifest() -> None:
    listed = yaml.safe_load((MANIFESTS / "kustomization.yaml").read_text())["resources"]
    present = sorted(p.name for p in MANIFESTS.glob("*.yaml") if p.name != "kustomization.yaml")
    assert sorted(listed) == present
    kinds = sorted(d["kind"] for d in _documents())
    assert kinds == sorted(
        ["ConfigMap", "Deployment", "Job", "PodDisruptionBudget", "Secret", "Service"]
    )


def test_the_pods_run_attune_serve_on_the_probed_port(routes: set[str]) -> None:
    container = _container(_one("Deployment"))
    names, params = _command(container["command"])
    assert names == ["serve"]
    assert params["host"] == "0.0.0.0"
    assert params["migrate"] is False  # the Job migrates, once
    ports = {p["name"]: p["containerPort"] for p in container["ports"]}
    assert ports["http"] == params["port"]
    probes = {
        kind: container[kind]["httpGet"]
        for kind in ("startupProbe", "livenessProbe", "readinessProbe")
    }
    assert probes["livenessProbe"]["path"] == "/livez"
    assert probes["startupProbe"]["path"] == "/livez"
    assert probes["readinessProbe"]["path"] == "/readyz"
    for probe in probes.values():
        assert probe["path"] in routes, probe
        assert ports[probe["port"]] == params["port"], probe


def test_metrics_on_their_own_port(routes: set[str]) -> None:
    container = _container(_one("Deployment"))
    ports = {p["name"]: p["containerPort"] for p in container["ports"]}
    settings = _settings_env()
    assert ports["metrics"] == int(settings["ATTUNE_METRICS_PORT"])
    assert "/metrics" in routes
    assert "ATTUNE_METRICS_TOKEN" in _one("Secret")["stringData"]  # fleet names are private
    service = _one("Service")
    for port in service["spec"]["ports"]:
        assert port["targetPort"] in ports, port


def test_the_migration_job_runs_db_upgrade() -> None:
    job = _one("Job")
    container = _container(job)
    names, _ = _command(container["command"])
    assert names == ["db", "upgrade"]
    assert job["spec"]["template"]["spec"]["restartPolicy"] in ("Never", "OnFailure")
    # The same settings as the pods (the mission, the database).
    assert container["envFrom"] == _container(_one("Deployment"))["envFrom"]


def test_every_setting_is_one_of_the_service() -> None:
    env = _settings_env()
    fields = Settings.model_fields
    for name in env:
        assert name.startswith("ATTUNE_"), name
        assert name.removeprefix("ATTUNE_").lower() in fields, name
    # The values are valid settings (types, ranges, the database URL's shape).
    values = {name.removeprefix("ATTUNE_").lower(): value for name, value in env.items()}
    settings = Settings.model_validate(values)
    assert settings.metrics_port is not None
    assert not settings.is_sqlite
    for workload in (_one("Deployment"), _one("Job")):
        refs = _container(workload)["envFrom"]
        assert {r["configMapRef"]["name"] for r in refs if "configMapRef" in r} == {
            _one("ConfigMap")["metadata"]["name"]
        }
        assert {r["secretRef"]["name"] for r in refs if "secretRef" in r} == {
            _one("Secret")["metadata"]["name"]
        }


def test_the_drain_fits_in_the_grace_period() -> None:
    pod = _one("Deployment")["spec"]["template"]["spec"]
    container = _container(_one("Deployment"))
    pause = container["lifecycle"]["preStop"]["exec"]["command"]
    assert pause[0] == "sleep"
    drain = float(_settings_env()["ATTUNE_DRAIN_TIMEOUT_S"])
    # preStop, then SIGTERM and the drain, then the shutdown: all before Kubernetes' SIGKILL.
    assert float(pause[1]) + drain + 5 <= pod["terminationGracePeriodSeconds"]


def test_the_labels_tie_the_objects_together() -> None:
    deployment = _one("Deployment")
    labels = deployment["spec"]["template"]["metadata"]["labels"]
    selector = deployment["spec"]["selector"]["matchLabels"]
    assert selector.items() <= labels.items()
    assert _one("Service")["spec"]["selector"].items() <= labels.items()
    assert _one("PodDisruptionBudget")["spec"]["selector"]["matchLabels"].items() <= labels.items()
    assert deployment["spec"]["replicas"] >= 2  # the budget lets one pod go at a time
    # The migration Job's pods are not the Service's.
    job_labels = _one("Job")["spec"]["template"]["metadata"]["labels"]
    assert not _one("Service")["spec"]["selector"].items() <= job_labels.items()


def test_the_image_fits_the_pods() -> None:
    """The image docker/Dockerfile builds: its user, its port, and the only folder the pods
    write to (the root file system is read-only): the temporary one, for the metrics files."""
    _, stages = parse(DOCKERFILE)
    final = stages[-1]
    uid = int(final.all("USER")[-1].split(":")[0])
    exposed = {int(p) for text in final.all("EXPOSE") for p in text.split()}
    (health,) = final.all("HEALTHCHECK")
    assert "/livez" in health
    cmd = exec_form(final.all("CMD")[-1])
    assert cmd[:2] == ["attune", "serve"], shlex.join(cmd)
    for workload in (_one("Deployment"), _one("Job")):
        pod = workload["spec"]["template"]["spec"]
        assert pod["securityContext"]["runAsUser"] == uid
        container = _container(workload)
        assert container["securityContext"]["readOnlyRootFilesystem"] is True
    container = _container(_one("Deployment"))
    assert {p["containerPort"] for p in container["ports"] if p["name"] == "http"} <= exposed
    mounts = {m["mountPath"] for m in container["volumeMounts"]}
    assert "/tmp" in mounts  # PROMETHEUS_MULTIPROC_DIR is made there


def test_a_command_line_the_cli_does_not_know_is_refused() -> None:
    """The check above is a real parse: an unknown option or command fails it."""
    with pytest.raises(Exception, match="bogus"):
        _command(["attune", "serve", "--bogus"])
    with pytest.raises(Exception, match="migrate-everything"):
        _command(["attune", "db", "migrate-everything"])
