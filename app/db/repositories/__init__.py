"""All SQL lives here: functions that take a session and domain arguments (options keyword-only)
and return ORM objects, plain rows or ``None``. They never commit."""
