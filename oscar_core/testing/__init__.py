"""Testing helpers for oscar and for plugin authors: golden-image comparison.

Names load on first use, so that the pytest plugin (``oscar_core.testing.pytest_plugin``)
imports neither numpy nor OpenCV when pytest starts.
"""

from __future__ import annotations

import importlib

__all__ = ["assert_matches_golden", "compare_images", "read_png", "write_png"]


def __getattr__(name: str):
    if name not in __all__:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(".golden", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return __all__
