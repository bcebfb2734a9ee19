"""Lazy flat re-exports for packages whose submodules are slow to import."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping

from .deprecation import Deprecated, warn_deprecated


def lazy_exports(
    package: str, exports: Mapping[str, str], deprecated: Mapping[str, Deprecated] | None = None
) -> tuple[list[str], Callable, Callable]:
    """``(__all__, __getattr__, __dir__)`` for ``package``: each name in
    ``exports`` (name → submodule) is imported from its submodule on first
    access and then cached in the package's namespace.

    ``deprecated``: old name → :class:`~oscar_core._util.deprecation.Deprecated`; such a name still resolves to its
    value, warns on every access (it is not cached) and is left out of ``__all__`` and ``dir()``.

    Usage in a package ``__init__``::

        __all__, __getattr__, __dir__ = lazy_exports(__name__, {"Thing": "things"})
    """
    names = sorted(exports)
    old_names = dict(deprecated or {})

    def __getattr__(name: str):
        module = exports.get(name)
        if module is None:
            old = old_names.get(name)
            if old is None:
                raise AttributeError(f"module {package!r} has no attribute {name!r}")
            warn_deprecated(f"{package}.{name}", old.replacement, old.since, old.removed_in)
            return getattr(importlib.import_module(old.module), old.attribute)
        value = getattr(importlib.import_module(f".{module}", package), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__():
        return names

    return names, __getattr__, __dir__
