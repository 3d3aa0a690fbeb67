"""Experiment command line support: a parallel runner and the paper-style reports.

``runner`` runs methods x protocols x seeds (or a study's own tasks) in worker processes.
Every report is made with ``report``, the kit of what they share (the files, markdown and
terminal tables, shares of an oracle's reward and their intervals, figures); the paper's with
``statistics`` (the numbers), ``plots`` (the figures), ``text`` (its tables) and ``outputs``
(its files); the studies each in their module (``robustness``, ``newcomers``,
``claims_map``).

Outside the pure learning core, so it may use rich, typer and matplotlib. Only the runner is
imported here: worker processes import this package, and they need neither plots nor tables.
"""

from .runner import Job, jobs_for, run_jobs

__all__ = ["Job", "jobs_for", "run_jobs"]
