"""All SQL lives here: one module per aggregate (users, models, episodes, keys, audit) plus the
console's reads. Every function takes the request's ``Session`` and domain arguments (options
keyword-only), runs Core statements on the session's connection, and returns plain records
(dataclasses of this package) or ``None``. Nothing here commits."""

from ._rows import batch

__all__ = ["batch"]
