"""Debian's nginx (``/usr/sbin/nginx``) as a process of the test, in front of ``attune serve``
instances, with the very site configuration the repository ships (``docker/nginx/attune.conf``).

``site_conf(upstreams, port, logs)`` is that file with what only Docker knows replaced: the
instances' addresses (``attune-1:8000``... become the live services' ``127.0.0.1:PORT``), the
port it listens on, where it logs. ``Nginx(upstreams, folder)`` runs nginx on it in ``folder``
(its prefix: the configuration, pid file, temporary files and logs), on a free port, not as a
daemon (``-p DIR -c CONF -e LOG -g 'daemon off;'``), until ``stop()``. Nothing outside
``folder`` is read or written but the shipped configuration.
"""

from __future__ import annotations

import os
import pwd
import re
import signal
import socket
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType

from tests.support.live import free_port

__all__ = ["NGINX", "SITE", "Nginx", "site_conf"]

NGINX = "/usr/sbin/nginx"
ROOT = Path(__file__).resolve().parents[2]
SITE = ROOT / "docker" / "nginx" / "attune.conf"
PREFIX = "/attune"

_SERVER = re.compile(r"^(\s*)server attune-\d+:8000\b([^;]*);$", re.M)


def site_conf(upstreams: Sequence[str], port: int, logs: Path) -> str:
    """The shipped site configuration for instances at ``upstreams`` (``HOST:PORT``), listening
    on 127.0.0.1:``port``, logging into ``logs``."""
    text = SITE.read_text()
    servers = _SERVER.findall(text)
    assert servers, f"no `server attune-N:8000` line in {SITE.name}"
    indent, options = servers[0]
    lines = "\n".join(f"{indent}server {where}{options};" for where in upstreams)
    text = _SERVER.sub("", text, count=len(servers) - 1)
    text = _SERVER.sub(lines.replace("\\", "\\\\"), text, count=1)
    text, listens = re.subn(r"^(\s*)listen 80;$", rf"\1listen 127.0.0.1:{port};", text, flags=re.M)
    assert listens == 1, "the site must listen on port 80 once"
    return text.replace("/var/log/nginx/", f"{logs}/")


def _main_conf(folder: Path, site: Path) -> str:
    temp = "\n".join(
        f"    {kind}_temp_path {folder / 'temp' / kind};"
        for kind in ("client_body", "proxy", "fastcgi", "uwsgi", "scgi")
    )
    # As root, nginx's workers would run as nobody, who cannot enter the test's folders.
    user = f"user {pwd.getpwuid(os.geteuid()).pw_name};\n" if os.geteuid() == 0 else ""
    return (
        f"{user}worker_processes 1;\n"
        f"pid {folder / 'nginx.pid'};\n"
        f"error_log {folder / 'error.log'} info;\n"
        "events { worker_connections 1024; }\n"
        "http {\n"
        f"{temp}\n"
        f"    access_log {folder / 'access.log'};\n"
        f"    include {site};\n"
        "}\n"
    )


class Nginx:
    """nginx on a free port of 127.0.0.1, proxying ``/attune/`` to ``upstreams``. ``url`` is the
    service's address through it (``http://127.0.0.1:PORT/attune``)."""

    def __init__(self, upstreams: Sequence[str], folder: Path) -> None:
        self.folder = folder
        self.port = free_port()
        self.origin = f"http://127.0.0.1:{self.port}"
        self.url = self.origin + PREFIX
        for kind in ("client_body", "proxy", "fastcgi", "uwsgi", "scgi"):
            (folder / "temp" / kind).mkdir(parents=True, exist_ok=True)
        self.site = folder / "attune.conf"
        self.site.write_text(site_conf(upstreams, self.port, folder))
        self.conf = folder / "nginx.conf"
        self.conf.write_text(_main_conf(folder, self.site))
        self.process: subprocess.Popen[bytes] | None = None

    def _command(self, *more: str) -> list[str]:
        error_log = str(self.folder / "error.log")
        return [NGINX, "-p", f"{self.folder}/", "-c", str(self.conf), "-e", error_log, *more]

    def check(self) -> subprocess.CompletedProcess[str]:
        """``nginx -t`` on the configuration."""
        return subprocess.run(
            self._command("-t"), capture_output=True, text=True, timeout=30, check=False
        )

    def start(self, timeout: float = 15) -> None:
        self.process = subprocess.Popen(
            self._command("-g", "daemon off;"),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        deadline = time.monotonic() + timeout
        while True:
            if self.process.poll() is not None:
                raise AssertionError(f"nginx exited with {self.process.returncode}:\n{self.log()}")
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=1):
                    return
            except OSError:
                pass
            if time.monotonic() > deadline:
                self.stop()
                raise AssertionError(f"nginx did not listen within {timeout} s:\n{self.log()}")
            time.sleep(0.05)

    def stop(self, timeout: float = 10) -> None:
        """SIGQUIT (nginx's graceful stop), then SIGKILL if it hangs."""
        if self.process is None or self.process.poll() is not None:
            return
        self.process.send_signal(signal.SIGQUIT)
        try:
            self.process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait(timeout=10)

    def log(self) -> str:
        """The end of nginx's error log (for assertion messages)."""
        try:
            return (self.folder / "error.log").read_text(errors="replace")[-4000:]
        except OSError:
            return ""

    def access(self) -> list[str]:
        """The site's access lines (``log_format attune``)."""
        try:
            return (self.folder / "attune.log").read_text(errors="replace").splitlines()
        except OSError:
            return []

    def __enter__(self) -> Nginx:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
