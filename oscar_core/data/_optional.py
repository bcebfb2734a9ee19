"""Optional dependencies of the data pipeline: the package-wide helper (:mod:`oscar_core._util.optional`)."""

from __future__ import annotations

from .._util.optional import require

__all__ = ["require"]
