"""Experiment command line support: a parallel runner and the paper-style reports.

``runner`` runs methods x protocols x seeds in worker processes; a report is made of
``statistics`` (the numbers), ``plots`` (the figures, matplotlib), ``text`` (markdown and
terminal tables, rich) and ``outputs`` (the files they are written to).

Outside the pure learning core, so it may use rich, typer and matplotlib. Only the runner is
imported here: worker processes import this package, and they need neither plots nor tables.
"""

from .runner import Job, jobs_for, run_jobs

__all__ = ["Job", "jobs_for", "run_jobs"]
