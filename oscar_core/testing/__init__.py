"""Testing helpers for oscar and for plugin authors: golden-image comparison.

Names load on first use, so that the pytest plugin (``oscar_core.testing.pytest_plugin``)
imports neither numpy nor OpenCV when pytest starts.
"""

from __future__ import annotations

from .._util.lazy import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(
    __name__, {name: "golden" for name in ("assert_matches_golden", "compare_images", "read_png", "write_png")}
)
