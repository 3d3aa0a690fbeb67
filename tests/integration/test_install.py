"""The standard install, as a new user does it: plain pip in a fresh virtualenv, no uv, no scripts.

The repository's files (as a clone would have them, uncommitted edits included) are copied to a
scratch folder; `pip install .` installs the service (not editable), and `attune serve`, started
from another folder with no settings, migrates its embedded SQLite database there and answers
/readyz. The client installs alone from `clients/python`, and the service's `fleet` extra
resolves with plain pip when the client is given on the same command line.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
import venv
from pathlib import Path

import httpx
import pytest

from tests.support.live import free_port

ROOT = Path(__file__).resolve().parents[2]

pytestmark = [pytest.mark.live, pytest.mark.slow]


def _clone(dest: Path) -> Path:
    """The repository's tracked and new (not ignored) files, copied to ``dest``."""
    listed = (
        subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT,
            capture_output=True,
            check=True,
        )
        .stdout.decode()
        .split("\0")
    )
    for name in filter(None, listed):
        src = ROOT / name
        if src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)
    return dest


def _env() -> dict[str, str]:
    """This process's environment without any ATTUNE_ setting or virtualenv of its own."""
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith("ATTUNE_") and k not in ("VIRTUAL_ENV", "PYTHONPATH")
    }
    env["PATH"] = os.pathsep.join(
        p for p in env.get("PATH", "").split(os.pathsep) if not p.startswith(sys.prefix)
    )
    return env


def _venv(path: Path) -> Path:
    venv.EnvBuilder(with_pip=True, clear=True).create(path)
    return path / "bin"


def _pip(bin_dir: Path, *args: str, cwd: Path) -> None:
    done = subprocess.run(
        [str(bin_dir / "python"), "-m", "pip", "install", "--quiet", *args],
        cwd=cwd,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
    assert done.returncode == 0, done.stdout + done.stderr


@pytest.fixture(scope="module")
def clone(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _clone(tmp_path_factory.mktemp("clone"))


def test_pip_install_then_serve_from_any_folder(clone: Path, tmp_path: Path) -> None:
    bin_dir = _venv(tmp_path / "venv")
    _pip(bin_dir, ".", cwd=clone)
    # Not editable: the package (migrations included) lives in the virtualenv.
    where = subprocess.run(
        [str(bin_dir / "python"), "-c", "import app.db.migrate as m; print(m.script_location())"],
        cwd=tmp_path,
        env=_env(),
        capture_output=True,
        text=True,
        check=True,
    )
    assert Path(where.stdout.strip()).is_relative_to(tmp_path / "venv"), where.stdout
    # The service's own dependencies do not include the fleet's client.
    client = subprocess.run(
        [str(bin_dir / "python"), "-c", "import attune_client"],
        cwd=tmp_path,
        env=_env(),
        capture_output=True,
        text=True,
    )
    assert client.returncode != 0

    folder = tmp_path / "elsewhere"
    folder.mkdir()
    port = free_port()
    log = tmp_path / "serve.log"
    with open(log, "wb") as out:
        server = subprocess.Popen(
            [str(bin_dir / "attune"), "serve", "--port", str(port)],
            cwd=folder,
            env=_env(),
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        deadline = time.monotonic() + 60
        while True:
            assert server.poll() is None, log.read_text()
            try:
                ready = httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=2)
                if ready.status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, (
                "attune serve was not ready in 60 s\n" + log.read_text()
            )
            time.sleep(0.2)
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)
    # The embedded default: ./attune.db in the folder it was started from.
    assert (folder / "attune.db").is_file()


def test_the_client_installs_alone(clone: Path, tmp_path: Path) -> None:
    bin_dir = _venv(tmp_path / "venv")
    _pip(bin_dir, "./clients/python", cwd=clone)
    done = subprocess.run(
        [
            str(bin_dir / "python"),
            "-c",
            "import attune_client, importlib.util as u; "
            "print(attune_client.Client.__name__, u.find_spec('app') is None)",
        ],
        cwd=tmp_path,
        env=_env(),
        capture_output=True,
        text=True,
        check=True,
    )
    assert done.stdout.split() == ["Client", "True"]


def test_the_fleet_extra_resolves_with_plain_pip(clone: Path, tmp_path: Path) -> None:
    bin_dir = _venv(tmp_path / "venv")
    _pip(bin_dir, "./clients/python", ".[fleet]", cwd=clone)
    done = subprocess.run(
        [str(bin_dir / "python"), "-c", "import attune_client, matplotlib, app.fleet"],
        cwd=tmp_path,
        env=_env(),
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
