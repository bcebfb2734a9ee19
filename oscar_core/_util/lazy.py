"""Lazy flat re-exports for packages whose submodules are slow to import."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping


def lazy_exports(package: str, exports: Mapping[str, str]) -> tuple[list[str], Callable, Callable]:
    """``(__all__, __getattr__, __dir__)`` for ``package``: each name in
    ``exports`` (name → submodule) is imported from its submodule on first
    access and then cached in the package's namespace.

    Usage in a package ``__init__``::

        __all__, __getattr__, __dir__ = lazy_exports(__name__, {"Thing": "things"})
    """
    names = sorted(exports)

    def __getattr__(name: str):
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f".{module}", package), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__():
        return names

    return names, __getattr__, __dir__
