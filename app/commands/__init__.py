"""Service commands of the ``attune`` CLI: serve, db, keys, models."""
