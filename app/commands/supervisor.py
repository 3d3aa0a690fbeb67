"""The supervisor of ``attune serve --workers N``: uvicorn's, telling why a worker died.

uvicorn's ``Multiprocess`` replaces a worker that died or stopped answering its health check,
logging only "Child process [pid] died". An operator needs the cause: the exit code, or the
signal that killed it (SIGKILL is most often the kernel's out-of-memory killer), or that it
hung. Imported by ``attune serve`` only when it runs more than one worker.
"""

from __future__ import annotations

import logging
import signal

from uvicorn.supervisors.multiprocess import Multiprocess, Process

__all__ = ["Supervisor", "describe_exit"]

log = logging.getLogger("attune.serve")

try:  # the exit code of a worker that could not start (uvicorn >= 0.30)
    from uvicorn.config import STARTUP_FAILURE
except ImportError:  # pragma: no cover
    STARTUP_FAILURE = 3


def describe_exit(exitcode: int) -> str:
    """``exited with code 1`` / ``was killed by signal SIGKILL (9)``."""
    if exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = "unknown"
        return f"was killed by signal {name} ({-exitcode})"
    return f"exited with code {exitcode}"


class Supervisor(Multiprocess):
    """uvicorn's supervisor, which says why each worker it replaces died.

    Its check, like uvicorn's: a worker that is gone, or that does not answer a health check in
    time, is replaced. The cause is read at the moment the worker is found gone (also when it
    died while the check waited for its answer), so a crash is never reported as a hang.
    """

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
            replacement = Process(self.config, self.sockets)
            replacement.start()
            self.processes[idx] = replacement
