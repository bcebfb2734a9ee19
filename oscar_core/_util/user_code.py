"""Importing a user's object from ``module:attr`` or ``path/to/file.py:attr`` (judges, policies)."""

from __future__ import annotations

import importlib
import importlib.util
from pathlib import Path

__all__ = ["import_attr"]


def import_attr(spec: str, kind: str):
    """The object ``attr`` of ``module:attr`` (imported) or ``path/to/file.py:attr`` (executed as a module named
    ``oscar_user_<kind>_<stem>``). Raises ValueError for a spec without both parts, FileNotFoundError for a
    missing ``.py`` file, and ImportError / AttributeError as the import raises them; callers turn these into
    their own one-line errors."""
    target, _, attr = spec.rpartition(":")
    if not target or not attr:
        raise ValueError(f"expected module:attr or path/to/file.py:attr, found {spec!r}")
    if target.endswith(".py"):
        path = Path(target)
        if not path.is_file():
            raise FileNotFoundError(target)
        mod_spec = importlib.util.spec_from_file_location(f"oscar_user_{kind}_{path.stem}", path)
        module = importlib.util.module_from_spec(mod_spec)
        mod_spec.loader.exec_module(module)
    else:
        module = importlib.import_module(target)
    return getattr(module, attr)
