"""Optional dependencies of the data pipeline: the package-wide helper (:mod:`oscar_core._optional`)."""

from __future__ import annotations

from .._optional import require

__all__ = ["require"]
