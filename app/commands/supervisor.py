"""The supervisor of ``attune serve --workers N``: uvicorn's, telling why a worker died.

uvicorn's ``Multiprocess`` replaces a worker that died or stopped answering its health check,
logging only "Child process [pid] died". An operator needs the cause: the exit code, or the
signal that killed it (SIGKILL is most often the kernel's out-of-memory killer), or that it
hung. Imported by ``attune serve`` only when it runs more than one worker.
"""

from __future__ import annotations

import logging
import signal

from uvicorn.supervisors.multiprocess import Multiprocess

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
    """uvicorn's supervisor, which says why each worker it replaces died."""

    def keep_subprocess_alive(self) -> None:
        if self.should_exit.is_set():
            super().keep_subprocess_alive()
            return
        before = list(self.processes)
        dead = set()
        for process in before:
            code = process.exitcode
            if code is None:
                continue
            dead.add(id(process))
            if code == STARTUP_FAILURE:
                log.error("Worker process %s failed to start (%s).", process.pid,
                          describe_exit(code))
            else:
                log.error("Worker process %s %s; starting a new one.", process.pid,
                          describe_exit(code))
        super().keep_subprocess_alive()
        for process in before:
            if id(process) not in dead and process not in self.processes:
                log.error("Worker process %s did not answer its health check within %s s; "
                          "killed it and started a new one.", process.pid,
                          self.config.timeout_worker_healthcheck)
