"""Paired comparisons of two rows scored on the same clips: mean difference and a bootstrap interval.

Two world models (or two conditions) rolled out on the same clips give paired
per-clip numbers; their difference per clip removes what the clips share (how
hard each clip is), so the interval of the mean difference is much tighter
than the two rows' own intervals. The interval is the percentile bootstrap:
the clips are resampled with replacement ``resamples`` times, seeded, and the
``(1 − level)/2`` and ``(1 + level)/2`` quantiles of the resampled means are
returned.
"""

from __future__ import annotations

import numpy as np

__all__ = ["paired_bootstrap_interval", "paired_difference"]


def paired_bootstrap_interval(
    diff, resamples: int = 2000, seed: int = 0, level: float = 0.95, rng: np.random.Generator | None = None
) -> tuple[float, float]:
    """Percentile-bootstrap interval of the mean of ``diff`` (N,) paired differences.

    Non-finite entries are left out (a metric undefined on a clip); (NaN, NaN) when none is left.
    ``rng`` (optional) replaces the seeded generator, so several intervals can share one stream.
    """
    if not 0 < level < 1:
        raise ValueError(f"level: expected a number in (0, 1), found {level!r}")
    if resamples < 1:
        raise ValueError(f"resamples: expected at least 1, found {resamples!r}")
    d = np.asarray(diff, dtype=np.float64).ravel()
    d = d[np.isfinite(d)]
    if d.size == 0:
        return float("nan"), float("nan")
    rng = rng if rng is not None else np.random.default_rng(seed)
    idx = rng.integers(0, d.size, size=(int(resamples), d.size))
    means = d[idx].mean(axis=1)
    tail = (1.0 - level) / 2 * 100
    return float(np.percentile(means, tail)), float(np.percentile(means, 100 - tail))


def paired_difference(
    row: dict, reference: dict, metric: str, resamples: int = 2000, seed: int = 0, level: float = 0.95
) -> dict:
    """``row − reference`` for ``metric`` over the clips both have a finite value for.

    row, reference: clip id → per-clip metrics (dicts holding ``metric``). Returns
    ``{"mean": …, "ci": [lo, hi], "clips": n}`` (mean NaN and ci [NaN, NaN] when no clip has both).
    """
    ids = sorted(set(row) & set(reference))
    a = np.array([row[i].get(metric, np.nan) for i in ids], dtype=np.float64)
    b = np.array([reference[i].get(metric, np.nan) for i in ids], dtype=np.float64)
    d = a - b
    ok = np.isfinite(d)
    lo, hi = paired_bootstrap_interval(d[ok], resamples, seed, level)
    return {"mean": float(d[ok].mean()) if ok.any() else float("nan"), "ci": [lo, hi], "clips": int(ok.sum())}
