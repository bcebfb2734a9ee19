"""Optional dependencies, checked in one place: ``require(module, extra)``."""

from __future__ import annotations

from importlib import import_module

__all__ = ["require"]


def require(module: str, extra: str):
    """Import ``module`` or raise ImportError naming ``pip install "oscar-wm[<extra>]"``."""
    try:
        return import_module(module)
    except ImportError as exc:
        raise ImportError(
            f'{module} is needed here and is not installed ({exc}); install it with: pip install "oscar-wm[{extra}]"'
        ) from None
