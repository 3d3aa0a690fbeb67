"""Stand-ins for modules and callables that are imported on first use.

The command line builds every command (and prints ``--help``) without SQLAlchemy, Alembic,
pydantic or numpy; a command imports what it needs when it runs. Modules that refer to such
names at module level bind them with these stand-ins (and import them for real under
``TYPE_CHECKING``, for the type checker and the import contracts).
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any

__all__ = ["LazyModule", "lazy_callable"]


class LazyModule:
    """Behaves as the module ``name`` (attribute access), importing it on first use."""

    def __init__(self, name: str) -> None:
        self._name = name
        self._module: ModuleType | None = None

    def __getattr__(self, attribute: str) -> Any:
        if attribute.startswith("__"):
            raise AttributeError(attribute)
        if self._module is None:
            self._module = importlib.import_module(self._name)
        return getattr(self._module, attribute)

    def __repr__(self) -> str:
        return f"<lazy module {self._name!r}>"


def lazy_callable(module: str, name: str) -> Any:
    """A function that imports ``module`` on its first call and calls its ``name`` with the
    same arguments (for classes and functions that are only ever called)."""

    def call(*args: Any, **kwargs: Any) -> Any:
        return getattr(importlib.import_module(module), name)(*args, **kwargs)

    call.__name__ = call.__qualname__ = name
    call.__doc__ = f"{module}.{name}, imported on first call."
    return call
