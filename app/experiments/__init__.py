"""Experiment command line support: a parallel runner and the paper-style reports.

Outside the pure learning core, so it may use rich, typer and matplotlib. Only the runner is
imported here: worker processes import this package, and they need neither plots nor tables.
"""

from .runner import Job, jobs_for, run_jobs

__all__ = ["Job", "jobs_for", "run_jobs"]
