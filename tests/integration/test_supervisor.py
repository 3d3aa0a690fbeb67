"""A worker's watch on its supervisor, on its own: the portable check (no Linux signal) that
SIGTERMs the worker once its parent is gone. The live tests (test_serve.py) run it inside
``attune serve``, where Linux's parent-death signal usually gets there first."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

# The parent starts the worker, says its pid, and waits to be killed; the worker runs the
# supervisor's watch and writes "terminated" when its SIGTERM arrives.
PARENT = """
import subprocess, sys, time
child = subprocess.Popen([sys.executable, "-c", sys.argv[1], sys.argv[2]])
print(child.pid, flush=True)
time.sleep(600)
"""
WORKER = """
import os, signal, sys, threading, time
from pathlib import Path
from app.commands import supervisor
done = Path(sys.argv[1])
signal.signal(signal.SIGTERM, lambda *_: (done.write_text("terminated"), os._exit(0)))
threading.Thread(target=supervisor._watch_parent, args=(os.getppid(),), daemon=True).start()
done.with_suffix(".ready").write_text("watching")
time.sleep(600)
"""


def test_a_worker_whose_parent_dies_gets_sigterm(tmp_path: Path) -> None:
    done = tmp_path / "worker.txt"
    parent = subprocess.Popen(
        [sys.executable, "-c", PARENT, WORKER, str(done)],
        stdout=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        assert parent.stdout is not None
        assert int(parent.stdout.readline()) > 0  # the worker's pid
        for _ in range(600):  # the worker imports the app's modules first
            if done.with_suffix(".ready").exists():
                break
            time.sleep(0.1)
        assert done.with_suffix(".ready").exists(), "the worker did not start watching"
        assert not done.exists()  # its parent lives: nothing happens
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(timeout=30)
        for _ in range(300):
            if done.exists():
                break
            time.sleep(0.1)
        assert done.read_text() == "terminated"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(parent.pid, signal.SIGKILL)  # the worker is in its group
        parent.wait(timeout=30)
        if parent.stdout is not None:
            parent.stdout.close()
