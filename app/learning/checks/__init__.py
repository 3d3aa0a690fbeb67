"""The conformance suite every learner must pass, split as an environment checker is: the
per-call invariant checks (:mod:`.invariants`) and the driver that exercises a learner in phases
and calls through them (:mod:`.suite`, :func:`check_learner`).
"""

from .suite import check_learner

__all__ = ["check_learner"]
