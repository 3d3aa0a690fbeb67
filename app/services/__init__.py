"""Use cases: load state, run the learning core, save; raise ``AppError``; never commit.

The request (``app.api.deps``) or the command (``app.cli``) owns the transaction.
"""
