"""argparse ``type=`` functions that refuse what a bare ``int``/``float`` lets through."""

from __future__ import annotations

import argparse
import math

__all__ = ["interval"]


def interval(text: str) -> tuple[float, float]:
    """``LO,HI`` → (lo, hi): two finite numbers with 0 <= LO <= HI <= 1 (a range of noise levels)."""
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        lo, hi = float(parts[0]), float(parts[1])
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LO,HI (two numbers), found {text!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo <= hi <= 1.0):
        raise argparse.ArgumentTypeError(f"expected 0 <= LO <= HI <= 1, found {text!r}")
    return lo, hi
