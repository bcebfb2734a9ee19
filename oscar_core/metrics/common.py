"""Shared helpers of the metrics package: the error type and input checks.

Private module; the public names are re-exported from ``oscar_core.metrics``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from ..errors import InputFileError

__all__ = ["MetricInputError", "align_policy_values", "finite_float", "nan_to_none", "percentile_interval"]


class MetricInputError(InputFileError):
    """Bad input to a metric.

    Like every oscar input error, the message names the input (a file, or the
    argument standing for one, e.g. ``real`` or ``preferences[3]``), the field,
    what was expected and what was found.
    """


def finite_float(value, source: str, field: str) -> float:
    """``value`` as a finite float, or a :class:`MetricInputError`."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise MetricInputError(source, field, "a number", f"{value!r} ({type(value).__name__})")
    out = float(value)
    if not math.isfinite(out):
        raise MetricInputError(source, field, "a finite number", repr(out))
    return out


def percentile_interval(values) -> list[float] | None:
    """The 95 % percentile interval ``[2.5th, 97.5th]`` of a bootstrap's values, leaving out the undefined ones
    (None, NaN); None when no value is defined."""
    ok = np.asarray([v for v in np.ravel(np.asarray(values, dtype=object)) if v is not None], dtype=float)
    ok = ok[np.isfinite(ok)]
    return [float(np.percentile(ok, 2.5)), float(np.percentile(ok, 97.5))] if ok.size else None


def nan_to_none(value):
    """JSON has no NaN/inf: map them to ``None`` (recursively through dicts and lists)."""
    if isinstance(value, dict):
        return {k: nan_to_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [nan_to_none(v) for v in value]
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def align_policy_values(
    real, wm, *, names=None, real_name: str = "real", wm_name: str = "wm", min_policies: int = 2
) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """Align two per-policy value collections by policy name.

    ``real`` and ``wm`` are either both mappings ``{policy: value}`` (matched by
    key; the order is ``names`` if given, else ``real``'s key order) or both
    sequences of equal length (matched by position; ``names`` labels them, by
    default ``policy_0, policy_1, ...``).

    Returns ``(names, real_values, wm_values)`` with float64 arrays of shape (N,).
    """
    real_is_map, wm_is_map = isinstance(real, Mapping), isinstance(wm, Mapping)
    if real_is_map != wm_is_map:
        kinds = {True: "a mapping {policy: value}", False: "a sequence"}
        raise MetricInputError(
            wm_name, "type", f"the same kind of input as {real_name} ({kinds[real_is_map]})", kinds[wm_is_map]
        )
    if real_is_map:
        real_keys, wm_keys = [str(k) for k in real], [str(k) for k in wm]
        missing = [k for k in real_keys if k not in set(wm_keys)]
        extra = [k for k in wm_keys if k not in set(real_keys)]
        if missing or extra:
            found = []
            if missing:
                found.append(f"missing {missing}")
            if extra:
                found.append(f"extra {extra}")
            raise MetricInputError(
                wm_name, "policy names", f"the same policies as {real_name} {sorted(real_keys)}", "; ".join(found)
            )
        if names is None:
            order = real_keys
        else:
            order = [str(n) for n in names]
            if sorted(order) != sorted(real_keys) or len(set(order)) != len(order):
                raise MetricInputError("names", "policy names", f"each of {sorted(real_keys)} exactly once", order)
        real_map = {str(k): v for k, v in real.items()}
        wm_map = {str(k): v for k, v in wm.items()}
        r = [finite_float(real_map[n], real_name, f"{n}") for n in order]
        w = [finite_float(wm_map[n], wm_name, f"{n}") for n in order]
    else:
        for src, seq in ((real_name, real), (wm_name, wm)):
            if isinstance(seq, (str, bytes)) or not isinstance(seq, (Sequence, np.ndarray)):
                raise MetricInputError(
                    src, "type", "a mapping {policy: value} or a sequence of numbers", type(seq).__name__
                )
        real_arr, wm_arr = np.asarray(real, dtype=object), np.asarray(wm, dtype=object)
        if real_arr.ndim != 1 or wm_arr.ndim != 1:
            raise MetricInputError(
                real_name if real_arr.ndim != 1 else wm_name,
                "shape",
                "a flat sequence (N,)",
                f"shape {real_arr.shape if real_arr.ndim != 1 else wm_arr.shape}",
            )
        if len(real_arr) != len(wm_arr):
            raise MetricInputError(
                wm_name,
                "length",
                f"{len(real_arr)} values (one per policy, as in {real_name})",
                f"{len(wm_arr)} values",
            )
        if names is None:
            order = [f"policy_{k}" for k in range(len(real_arr))]
        else:
            order = [str(n) for n in names]
            if len(order) != len(real_arr):
                raise MetricInputError(
                    "names", "length", f"{len(real_arr)} names (one per value)", f"{len(order)} names"
                )
            if len(set(order)) != len(order):
                dup = sorted({n for n in order if order.count(n) > 1})
                raise MetricInputError("names", "policy names", "unique names", f"duplicates {dup}")
        r = [finite_float(v, real_name, f"[{k}] ({order[k]})") for k, v in enumerate(real_arr)]
        w = [finite_float(v, wm_name, f"[{k}] ({order[k]})") for k, v in enumerate(wm_arr)]
    if len(order) < min_policies:
        raise MetricInputError(
            real_name, "number of policies", f"at least {min_policies} policies to compare", f"{len(order)}"
        )
    return tuple(order), np.asarray(r, dtype=np.float64), np.asarray(w, dtype=np.float64)
