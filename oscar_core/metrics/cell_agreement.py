"""Does a world model's verdict on each cell agree with the truth's: per-cell agreement, Cohen's κ, and how often
two policies the truth tells apart are told apart, each with a 95 % interval over sessions.

A ranking (ρ, MMRV) can be right for the wrong cells; these figures look at the cells themselves. Inputs are the
(S, P) matrices :func:`~oscar_core.metrics.policy_seeds.cell_rates` builds: ``real`` the truth's outcome (0/1,
NaN where unknown), ``wm`` the world model's verdict (0/1, or a seed average in [0, 1]; NaN where not judged). A
seed average is a vote: it counts as 1 at 0.5 or more.

Undefined figures are None with a reason in words beside them (``*_why``), never NaN: κ with one rater constant
and equal to the other (chance agreement 1), a pair the truth never tells apart, no session to resample.
"""

from __future__ import annotations

import numpy as np

from .common import percentile_interval

__all__ = ["cell_agreement", "cohen_kappa", "pair_separation", "agreement_summary"]


def _votes(real: np.ndarray, wm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(truth, verdict) 1-D 0/1 arrays of the cells both sides judged."""
    real, wm = np.asarray(real, float), np.asarray(wm, float)
    ok = np.isfinite(real) & np.isfinite(wm)
    return (real[ok] >= 0.5).astype(int), (wm[ok] >= 0.5).astype(int)


def cell_agreement(real: np.ndarray, wm: np.ndarray) -> float | None:
    """Fraction of the judged cells whose verdict equals the truth; None with no judged cell."""
    t, v = _votes(real, wm)
    return float(np.mean(t == v)) if t.size else None


def cohen_kappa(real: np.ndarray, wm: np.ndarray) -> tuple[float | None, str | None]:
    """(κ, why undefined): Cohen's κ = (p_o − p_e) / (1 − p_e) between truth and verdict over the judged cells,
    p_e the agreement expected from each side's own rate of successes. Undefined (None, a reason) with no judged
    cell or when p_e = 1 (both sides give every cell the same outcome)."""
    t, v = _votes(real, wm)
    if not t.size:
        return None, "no cell was judged by both the world model and the truth"
    po = float(np.mean(t == v))
    pt, pv = float(np.mean(t)), float(np.mean(v))
    pe = pt * pv + (1 - pt) * (1 - pv)
    if pe >= 1.0 - 1e-12:
        side = "success" if pt == 1.0 else "failure"
        return None, f"both sides judge every one of the {t.size} cells a {side}: chance agreement is 1"
    return (po - pe) / (1.0 - pe), None


def pair_separation(real: np.ndarray, wm: np.ndarray, a: int, b: int) -> tuple[float | None, int, str | None]:
    """(fraction, sessions, why undefined): of the sessions where the truth's outcomes of policies ``a`` and ``b``
    (column indices) differ, the fraction where the world model's verdicts differ the same way round."""
    real, wm = np.asarray(real, float), np.asarray(wm, float)
    ok = np.isfinite(real[:, a]) & np.isfinite(real[:, b]) & np.isfinite(wm[:, a]) & np.isfinite(wm[:, b])
    ta, tb = real[ok, a] >= 0.5, real[ok, b] >= 0.5
    va, vb = wm[ok, a] >= 0.5, wm[ok, b] >= 0.5
    differ = ta != tb
    n = int(differ.sum())
    if not n:
        return None, 0, "the truth gives the two policies the same outcome in every session judged"
    same_way = (va[differ] == ta[differ]) & (vb[differ] == tb[differ])
    return float(np.mean(same_way)), n, None


def agreement_summary(
    real: np.ndarray, wm: np.ndarray, policies: list[str], pairs=(), resamples: int = 2000, seed: int = 0
) -> dict:
    """Per-cell agreement and κ (with their 95 % session-bootstrap intervals), the agreement per policy, and for
    each (policy a, policy b) in ``pairs`` the separation of :func:`pair_separation` with its interval.

    real, wm: (S, P) with columns in ``policies``' order; pairs of names not in ``policies`` are skipped. Every
    undefined figure is None with a ``*_why`` sentence beside it.
    """
    real, wm = np.asarray(real, float), np.asarray(wm, float)
    sessions = real.shape[0]
    kappa, kappa_why = cohen_kappa(real, wm)
    out: dict = {
        "sessions": int(sessions),
        "cells_judged": int((np.isfinite(real) & np.isfinite(wm)).sum()),
        "agreement": cell_agreement(real, wm),
        "kappa": kappa,
        "kappa_why": kappa_why,
        "per_policy_agreement": {p: cell_agreement(real[:, i], wm[:, i]) for i, p in enumerate(policies)},
        "pairs": {},
        "resamples": int(resamples),
        "seed": int(seed),
    }
    index = {p: i for i, p in enumerate(policies)}
    wanted = [(a, b) for a, b in pairs if a in index and b in index]
    for a, b in wanted:
        frac, n, why = pair_separation(real, wm, index[a], index[b])
        out["pairs"][f"{a} vs {b}"] = {"separated": frac, "sessions": n, "why": why}
    if sessions < 2:
        why = f"{sessions} session: an interval over sessions needs at least 2"
        out.update(agreement_ci95=None, kappa_ci95=None, ci95_why=why)
        for pair in out["pairs"].values():
            pair["ci95"] = None
        return out
    rng = np.random.default_rng(seed)
    agree, kap, seps = [], [], {k: [] for k in out["pairs"]}
    for _ in range(int(resamples)):
        idx = rng.integers(0, sessions, sessions)
        r, w = real[idx], wm[idx]
        agree.append(cell_agreement(r, w))
        kap.append(cohen_kappa(r, w)[0])
        for a, b in wanted:
            seps[f"{a} vs {b}"].append(pair_separation(r, w, index[a], index[b])[0])
    out["agreement_ci95"], out["kappa_ci95"] = percentile_interval(agree), percentile_interval(kap)
    out["ci95_why"] = None if out["kappa_ci95"] is not None else "κ is undefined in every resample"
    for k, vals in seps.items():
        out["pairs"][k]["ci95"] = percentile_interval(vals)
    return out
