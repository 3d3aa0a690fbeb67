"""Commands of the ``attune`` CLI, one module per command group: serve, db, keys, models and
fleet (``_setup`` holds what the service's commands share)."""
