"""How ``attune serve`` runs its workers: each drains on SIGTERM or SIGINT, leaves with its
supervisor, and the supervisor tells why a worker died.

:class:`DrainingServer` is uvicorn's server with a drain: on the first SIGTERM or SIGINT it
tells the app (whose ``/readyz`` then answers 503), goes on serving while requests are in
flight, and stops accepting connections once none is, or once ``ATTUNE_DRAIN_TIMEOUT_S`` has
passed; then uvicorn's shutdown lets the last responses go out (within what is left of the
timeout) and exits. A second SIGINT (Ctrl+C twice) stops at once.

With ``--workers N``, :class:`Supervisor` (uvicorn's, telling why a worker died) runs each worker
as a :class:`Worker`: a process that serves with a :class:`DrainingServer` and that stops, by
the same drain, when its supervisor is gone (even after ``kill -9``, which the supervisor cannot
catch), so that no orphan keeps the port. Imported by ``attune serve`` only.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import logging
import math
import os
import signal
import sys
import threading
import time
from socket import socket
from types import FrameType

import uvicorn
from uvicorn.supervisors.multiprocess import Multiprocess, Process

__all__ = ["DrainingServer", "Supervisor", "Worker", "describe_exit"]

log = logging.getLogger("attune.serve")

try:  # the exit code of a worker that could not start (uvicorn >= 0.30)
    from uvicorn.config import STARTUP_FAILURE
except ImportError:  # pragma: no cover
    STARTUP_FAILURE = 3

DRAIN_STATE_KEY = "attune.drain"
"""Where the app's lifespan state holds its drain (``app.api.lifecycle.STATE_KEY``; the commands
do not import the HTTP layer)."""

PARENT_POLL_S = 1.0
"""How often a worker checks that its supervisor is still there (besides Linux's signal)."""

_PR_SET_PDEATHSIG = 1


def describe_exit(exitcode: int) -> str:
    """``exited with code 1`` / ``was killed by signal SIGKILL (9)``."""
    if exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = "unknown"
        return f"was killed by signal {name} ({-exitcode})"
    return f"exited with code {exitcode}"


class DrainingServer(uvicorn.Server):
    """uvicorn's server, draining on SIGTERM and SIGINT for up to ``drain_timeout`` seconds."""

    def __init__(
        self, config: uvicorn.Config, drain_timeout: float, *, supervisor: int | None = None
    ) -> None:
        super().__init__(config)
        self.drain_timeout = drain_timeout
        self.supervisor = supervisor  # a worker's: the process whose death stops it
        self.drain_deadline: float | None = None
        self._told = False
        self._told_orphaned = False

    async def startup(self, sockets: list[socket] | None = None) -> None:
        await super().startup(sockets)
        # What the worker made to start (the modules, the app, its routes, the engine) lives
        # as long as the worker: out of the garbage collector's reach, so that a full
        # collection scans only what requests made. Each one held the event loop up for 70 to
        # 220 ms with everything in reach (the robots' loop, PostgreSQL, a busy machine).
        gc.collect()
        gc.freeze()

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        # A signal handler: it only notes the time; the event loop does the rest (on_tick).
        # Unlike uvicorn's, it does not raise the signal again once the server stopped: a
        # drained worker exits with status 0.
        if self.drain_deadline is None:
            self.drain_deadline = time.monotonic() + self.drain_timeout
        elif sig == signal.SIGINT:  # Ctrl+C again: stop now
            self.should_exit = self.force_exit = True

    async def on_tick(self, counter: int) -> bool:
        deadline = self.drain_deadline
        if deadline is not None and not self.should_exit:
            if not self._told:
                self._told = True
                self._begin_drain()
            now = time.monotonic()
            if not self.server_state.tasks or now >= deadline:
                # No request in flight (or no time left): stop accepting, let the last
                # responses out in what is left of the timeout, then exit.
                self.config.timeout_graceful_shutdown = max(1, math.ceil(deadline - now))
                self.should_exit = True
        return await super().on_tick(counter)

    async def shutdown(self, sockets: list[socket] | None = None) -> None:
        await super().shutdown(sockets)
        # A supervisor killed with SIGKILL may still be this process's parent when the drain
        # begins: the kernel signals the worker (PR_SET_PDEATHSIG) as the thread that made
        # it exits, and makes it another thread's child while the rest of the supervisor
        # exits. It is gone by the time the drain is over.
        self._say_if_orphaned()

    def _say_if_orphaned(self) -> None:
        """Say, once, that the supervisor is gone, if this worker's parent is no longer it."""
        if self._told_orphaned or self.supervisor is None or os.getppid() == self.supervisor:
            return
        self._told_orphaned = True
        log.error(
            "The supervisor (process %s) is gone; worker process %s stops.",
            self.supervisor,
            os.getpid(),
        )

    def _begin_drain(self) -> None:
        lifespan = getattr(self, "lifespan", None)
        drain = getattr(lifespan, "state", {}).get(DRAIN_STATE_KEY)
        if drain is not None:
            drain.begin()
        self._say_if_orphaned()
        log.info(
            "Worker process %s is shutting down: it finishes the requests in flight (at most "
            "%g s), then exits.",
            os.getpid(),
            self.drain_timeout,
        )


class Worker(Process):
    """A worker process of :class:`Supervisor`: a :class:`DrainingServer` that stops when its
    supervisor is gone."""

    def __init__(self, config: uvicorn.Config, sockets: list[socket], drain_timeout: float) -> None:
        # Set before the process is made (it is pickled with it). The supervisor's id is taken
        # here, not read in the worker: a worker that starts after its supervisor died must see
        # that it is gone, not adopt its new parent.
        self.drain_timeout = drain_timeout
        self.supervisor = os.getpid()
        super().__init__(config, sockets)

    @property
    def server(self) -> uvicorn.Server:
        if self._server is None:
            self._server = DrainingServer(self.config, self.drain_timeout)
        return self._server

    def target(self, sockets: list[socket] | None = None) -> None:  # pragma: no cover
        # In the worker process (spawned): uvicorn's, with the supervisor watched and a health
        # check that ends quietly when the supervisor's end of the pipe closes.
        self._server = DrainingServer(self.config, self.drain_timeout, supervisor=self.supervisor)
        _leave_with(self.supervisor)
        threading.Thread(target=self._answer_health_checks, daemon=True).start()
        self._server.run(sockets)

    def _answer_health_checks(self) -> None:
        with contextlib.suppress(EOFError, OSError):
            while True:
                self.pong()


def _leave_with(parent: int) -> None:
    """SIGTERM this process, once, when ``parent`` is no longer its parent (or already is not):
    at once on Linux (the kernel's parent-death signal), within :data:`PARENT_POLL_S`
    elsewhere."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    threading.Thread(
        target=_watch_parent, args=(parent,), daemon=True, name="attune-parent"
    ).start()


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:  # the parent may be gone already, before prctl took effect
        time.sleep(PARENT_POLL_S)
    os.kill(os.getpid(), signal.SIGTERM)  # the drain says why (DrainingServer)


def _forget(pid: int | None) -> None:
    """Drop a worker that is gone from the metrics' live gauges (its counters stay summed)."""
    if pid is None or not os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
        return
    from prometheus_client.multiprocess import mark_process_dead

    with contextlib.suppress(OSError):
        mark_process_dead(pid)  # type: ignore[no-untyped-call]


class Supervisor(Multiprocess):
    """uvicorn's supervisor, whose workers drain and leave with it, and which says why each
    worker it replaces died.

    Its check, like uvicorn's: a worker that is gone, or that does not answer a health check in
    time, is replaced. The cause is read at the moment the worker is found gone (also when it
    died while the check waited for its answer), so a crash is never reported as a hang. When it
    stops (SIGTERM, SIGINT), every worker drains; one still running ``drain_timeout`` seconds
    (and a margin) later is killed.
    """

    def __init__(
        self, config: uvicorn.Config, sockets: list[socket], *, drain_timeout: float
    ) -> None:
        super().__init__(config, sockets)
        self.drain_timeout = drain_timeout

    def _worker(self) -> Worker:
        worker = Worker(self.config, self.sockets, self.drain_timeout)
        worker.start()
        return worker

    def init_processes(self) -> None:
        for _ in range(self.processes_num):
            self.processes.append(self._worker())

    def join_all(self) -> None:
        deadline = time.monotonic() + self.drain_timeout + 10  # the drain, then the shutdown
        for process in self.processes:
            process.process.join(max(0.0, deadline - time.monotonic()))
            if process.process.is_alive():
                log.error(
                    "Worker process %s did not stop within %g s of the drain; killed it.",
                    process.pid,
                    self.drain_timeout,
                )
                process.kill()
                process.process.join()
            _forget(process.pid)

    def restart_all(self) -> None:
        # SIGHUP: replace each worker by a new one, as uvicorn does, with workers of ours.
        for idx, old in enumerate(self.processes):
            if self.should_exit.is_set():
                return
            new = self._worker()
            if not new.wait_until_ready(self.config.timeout_worker_healthcheck, self.should_exit):
                new.kill()
                new.join()
                return
            old.terminate()
            old.join()
            _forget(old.pid)
            self.processes[idx] = new

    def handle_ttin(self) -> None:
        self.processes_num += 1
        self.processes.append(self._worker())

    def keep_subprocess_alive(self) -> None:
        if self.should_exit.is_set():
            return  # the supervisor is stopping: no new workers
        timeout = self.config.timeout_worker_healthcheck
        for idx, process in enumerate(self.processes):
            if process.process.is_alive() and process.ping(timeout):
                continue
            hung = process.process.is_alive()  # still running: it did not answer in time
            process.kill()
            process.join()
            _forget(process.pid)
            code = process.exitcode
            if hung:
                log.error(
                    "Worker process %s did not answer its health check within %s s; "
                    "killed it and started a new one.",
                    process.pid,
                    timeout,
                )
            elif code == STARTUP_FAILURE:
                # The app, the socket or the settings are broken: every restart would fail too.
                log.error(
                    "Worker process %s failed to start (%s); stopping.",
                    process.pid,
                    describe_exit(code),
                )
                self.should_exit.set()
                return
            else:
                log.error(
                    "Worker process %s %s; starting a new one.",
                    process.pid,
                    describe_exit(code if code is not None else 0),
                )
            if self.should_exit.is_set():
                return
            self.processes[idx] = self._worker()
