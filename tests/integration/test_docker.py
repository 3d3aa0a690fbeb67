"""The docker/ files, checked without a Docker engine.

No engine runs here, so the image is never built. What can be checked is checked: hadolint on the
Dockerfile; the compose file's wiring (PostgreSQL healthy before the service, the service healthy
on /readyz); and the image's own commands, run here at a scratch root: the build stage's COPY and
RUN steps, then the final stage's CMD and HEALTHCHECK against what they built.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from app.settings import Settings
from tests.support.live import free_port

ROOT = Path(__file__).resolve().parents[2]
DOCKERFILE = ROOT / "docker" / "Dockerfile"
COMPOSE = ROOT / "docker" / "compose.yml"


@dataclass
class Stage:
    name: str | None
    base: str
    instructions: list[tuple[str, str]] = field(default_factory=list)

    def all(self, keyword: str) -> list[str]:
        return [args for kw, args in self.instructions if kw == keyword]


def parse(path: Path) -> tuple[dict[str, str], list[Stage]]:
    """(global ARGs, stages) of a Dockerfile: continuation lines joined, comments dropped."""
    logical: list[str] = []
    pending = ""
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not pending and (not line or line.startswith("#")):
            continue
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        logical.append(pending + line)
        pending = ""
    args: dict[str, str] = {}
    stages: list[Stage] = []
    for line in logical:
        keyword, _, rest = line.partition(" ")
        keyword = keyword.upper()
        if keyword == "FROM":
            parts = rest.split()
            name = parts[2] if len(parts) == 3 and parts[1].upper() == "AS" else None
            stages.append(Stage(name, parts[0]))
        elif stages:
            stages[-1].instructions.append((keyword, rest.strip()))
        elif keyword == "ARG":
            key, _, value = rest.partition("=")
            args[key] = value
    return args, stages


def exec_form(args: str) -> list[str]:
    value = json.loads(args)
    assert isinstance(value, list), f"use the exec form (a JSON list), not a shell string: {args}"
    return [str(v) for v in value]


def test_hadolint_finds_nothing() -> None:
    hadolint = Path(sys.executable).with_name("hadolint")
    done = subprocess.run(
        [str(hadolint), str(DOCKERFILE)], capture_output=True, text=True, check=False, timeout=60
    )
    assert done.returncode == 0, done.stdout + done.stderr


def test_image_shape() -> None:
    args, stages = parse(DOCKERFILE)
    assert len(stages) == 2
    build, final = stages
    assert build.name == "build"
    assert final.base == build.base == "${PYTHON_IMAGE}"
    assert args["PYTHON_IMAGE"].startswith("python:3.11-slim")
    # Nothing in the final stage installs packages or copies in uv: no build tools there.
    for kw, text in final.instructions:
        if kw == "RUN":
            assert not any(word in text for word in ("apt-get", "pip", "uv ", "gcc")), text
    # The final stage holds the virtualenv alone: the service is installed in it, not editable,
    # with its migrations inside the package (no source tree beside it).
    assert final.all("COPY") == ["--from=build /opt/venv /opt/venv"]
    # The build stage installs from the lock file, never by resolving anew.
    syncs = [text for text in build.all("RUN") if "uv sync" in text]
    assert syncs, "the build stage installs with uv sync"
    assert all("--frozen" in text and "--no-editable" in text for text in syncs), syncs
    assert any("uv.lock" in text for text in build.all("COPY"))
    user = final.all("USER")[-1]
    uid = user.split(":")[0]
    assert uid.isdigit(), user
    assert int(uid) >= 1000, user
    (health,) = final.all("HEALTHCHECK")
    assert "/livez" in health
    assert exec_form(final.all("CMD")[-1])[:2] == ["attune", "serve"]


def test_compose_wiring() -> None:
    doc: dict[str, Any] = yaml.safe_load(COMPOSE.read_text())
    db, attune = doc["services"]["db"], doc["services"]["attune"]
    assert db["image"].startswith("postgres:")
    assert "pg_isready" in " ".join(db["healthcheck"]["test"])
    assert attune["depends_on"] == {"db": {"condition": "service_healthy"}}
    assert (COMPOSE.parent / attune["build"]["context"] / attune["build"]["dockerfile"]).samefile(
        DOCKERFILE
    )
    url = attune["environment"]["ATTUNE_DATABASE_URL"]
    assert url.startswith("postgresql://attune:")
    assert url.endswith("@db:5432/attune")
    assert "/readyz" in " ".join(attune["healthcheck"]["test"])
    assert attune["command"][:2] == ["attune", "serve"]
    assert "--workers" in attune["command"]
    # Docker waits this long after SIGTERM before SIGKILL: longer than the service's drain.
    grace = attune["stop_grace_period"]
    assert grace.endswith("s")
    assert int(grace[:-1]) > Settings.model_fields["drain_timeout_s"].default
    assert "pgdata" in doc["volumes"]


def _run_build_stage(stage: Stage, root: Path, venv: Path) -> Path:
    """The build stage's ENV, COPY and ``uv sync`` steps with / moved to ``root`` and the
    image's Python replaced by this machine's; returns the workdir. (uv's cache is left on here:
    the image turns it off only to keep its layers small.)"""
    workdir = root
    python = shutil.which("python3") or sys.executable
    env = dict(os.environ)

    def here(text: str) -> str:
        return text.replace("/opt/venv", str(venv)).replace("/usr/local/bin/python3", python)

    for kw, text in stage.instructions:
        if kw == "ENV":
            for item in shlex.split(text):
                name, _, value = item.partition("=")
                if name != "UV_NO_CACHE":
                    env[name] = here(value)
        elif kw == "WORKDIR":
            workdir = root / text.lstrip("/")
            workdir.mkdir(parents=True, exist_ok=True)
        elif kw == "COPY":
            *sources, dest = text.split()
            target = workdir / dest
            for source in sources:
                src = ROOT / source
                if src.is_dir():
                    shutil.copytree(
                        src,
                        target,
                        dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns("__pycache__", "tests"),
                    )
                else:
                    target.mkdir(parents=True, exist_ok=True)
                    shutil.copy2(src, target / src.name)
        elif kw == "RUN" and "uv sync" in text:
            done = subprocess.run(
                ["bash", "-c", here(text)],
                cwd=workdir,
                env=env,
                capture_output=True,
                text=True,
                check=False,
                timeout=600,
            )
            assert done.returncode == 0, done.stdout + done.stderr
    return workdir


@pytest.mark.live
def test_the_image_commands_run_here(tmp_path: Path) -> None:
    if shutil.which("uv") is None:
        pytest.fail(
            "uv is needed to run the build stage's commands (./scripts/bootstrap installs it)",
            pytrace=False,
        )
    _, (build, final) = parse(DOCKERFILE)
    venv = tmp_path / "opt" / "venv"
    _run_build_stage(build, tmp_path / "root", venv)
    assert (venv / "bin" / "attune").exists()
    assert not (venv / "bin" / "uv").exists(), "uv belongs to the build stage only"
    # Installed, not linked to the source tree: the final stage has no source tree.
    installed = subprocess.run(
        [str(venv / "bin" / "python"), "-c", "import app, attune_client"],
        capture_output=True,
        text=True,
        check=False,
        timeout=60,
        cwd=tmp_path,
    )
    assert "No module named 'attune_client'" in installed.stderr, "no client in the image"
    located = subprocess.run(
        [
            str(venv / "bin" / "python"),
            "-c",
            "import app.db.migrate as m; print(m.script_location())",
        ],
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert located.stdout.strip().startswith(str(venv)), located.stdout
    workdir = tmp_path / "root" / "var" / "lib" / "attune"
    workdir.mkdir(parents=True)

    port = free_port()
    command = exec_form(final.all("CMD")[-1])
    command = [str(venv / "bin" / command[0]), *command[1:]]
    command[command.index("--host") + 1] = "127.0.0.1"  # loopback only, here
    command[command.index("--port") + 1] = str(port)
    env = {
        **os.environ,
        "PATH": f"{venv / 'bin'}:{os.environ['PATH']}",
        "ATTUNE_DATABASE_URL": f"sqlite:///{tmp_path / 'data' / 'attune.db'}",
        "ATTUNE_LOG_LEVEL": "warning",
    }
    (tmp_path / "data").mkdir()
    log = tmp_path / "serve.log"
    with open(log, "wb") as out:
        server = subprocess.Popen(
            command,
            cwd=workdir,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        deadline = time.monotonic() + 60
        while True:
            assert server.poll() is None, log.read_text()
            try:
                if httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, "the image's CMD did not become ready in 60 s"
            time.sleep(0.2)
        (health,) = final.all("HEALTHCHECK")
        check = exec_form(health.split(" CMD ", 1)[1])
        check = [c.replace("127.0.0.1:8000", f"127.0.0.1:{port}") for c in check]
        done = subprocess.run(
            check, env=env, capture_output=True, text=True, timeout=30, check=False
        )
        assert done.returncode == 0, done.stderr
        # The same check fails when nothing listens: it is a real check.
        closed = [c.replace(str(port), str(free_port())) for c in check]
        assert (
            subprocess.run(closed, env=env, capture_output=True, timeout=30, check=False).returncode
            != 0
        )
        keys = subprocess.run(
            [str(venv / "bin" / "attune"), "keys", "create", "--role", "robot"],
            cwd=workdir,
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        assert keys.returncode == 0, keys.stderr
        assert keys.stdout.strip().splitlines()[-1].startswith("att_")
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)
    assert shlex.join(command)  # the command as run, for a failing assertion's context
