"""Policy evaluation: how well world-model results rank and score real policies.

The paper (OSCAR, Sec. "Policy Evaluation" and Appendix "Metric definitions")
compares, for N policies, the results measured in the world model ("wm") with
the results measured on real robots ("real"):

* **MMRV** — Mean Maximum Rank Violation, in two forms:

  - :func:`mmrv_simpler` is SIMPLER's definition (``mean_maximum_rank_violation``
    in ``simpler_env/utils/metrics.py``): a pair of policies *violates* when the
    two results order it differently, and a violation costs the gap between the
    two policies' *real success rates*; each policy keeps its largest cost and
    MMRV is the mean over policies. Range [0, max real gap] (⊂ [0, 1] for rates).
  - :func:`mmrv_rank` is the form the OSCAR paper reports ("MMRV on the
    seven-policy rank vector, range [0, 6]"): the same violations, each costing
    the distance between the two policies' *real ranks*. Its true range is
    [0, :func:`mmrv_rank_max` (N)] with ``mmrv_rank_max(N) = 1/N Σ_i max(i − 1, N − i)``,
    reached by the reversed ranking: 33/7 ≈ 4.714 for the paper's N = 7, not
    the paper's stated 6 (N − 1 is reached only for N = 2).

* **Spearman ρ** between the per-policy rank vectors (:func:`spearman_rho`).
* **Pearson r** between per-policy mean binary success rates (:func:`pearson_r`).
* **SISR_Δ** = mean over policies of |SR_real − SR_wm|, in percentage points
  (:func:`sisr_delta`).

and fits **Bradley–Terry scores with Davidson ties** to pairwise preferences
(:func:`fit_bradley_terry`), the way RoboArena's leaderboard does.

Ties
----
Violations use strict comparisons exactly as SIMPLER does: policies i, j
violate iff ``(wm_i > wm_j) != (real_i > real_j)``. So a pair tied in the world
model but not in reality counts as a violation for the really-better policy
only (from the other policy's side both comparisons are False), and a pair tied
in reality costs 0 in either form (equal rates, equal average ranks). Ranks are
*average* ranks (``scipy.stats.rankdata(method="average")``), the convention of
``scipy.stats.spearmanr``; ranking a score vector this way keeps every strict
order and every tie, so both MMRV forms flag the same pairs.

Inputs
------
Every per-policy function takes ``real`` then ``wm``, either both mappings
``{policy: value}`` (matched by name; the key sets must agree) or both
sequences of equal length (matched by position, labelled by ``names``). At
least two policies are needed. Success rates are fractions in [0, 1]; ranking
scores (success rates, BT scores, Elo) are any finite numbers, higher = better.

The Bradley–Terry fit lives in :mod:`oscar_core.metrics.bradley_terry`; its public names are
re-exported here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .bradley_terry import (
    ELO_SCALE,
    ELO_SHIFT,
    BradleyTerryResult,
    BradleyTerryWarning,
    Preference,
    fit_bradley_terry,
    parse_preference,
)
from .common import MetricInputError, align_policy_values, nan_to_none

__all__ = [
    "mmrv_simpler",
    "mmrv_rank",
    "mmrv_rank_max",
    "spearman_rho",
    "pearson_r",
    "sisr_delta",
    "average_ranks",
    "success_rates",
    "PolicyComparison",
    "compare_policies",
    "Preference",
    "parse_preference",
    "BradleyTerryResult",
    "BradleyTerryWarning",
    "fit_bradley_terry",
    "ELO_SCALE",
    "ELO_SHIFT",
]


# --------------------------------------------------------------------------- #
# rank fidelity
# --------------------------------------------------------------------------- #
def average_ranks(values) -> np.ndarray:
    """Ascending average ranks (1 = lowest value; ties share the mean rank).

    ``values``: (N,) finite numbers. Returns (N,) float64 ranks in [1, N], the
    same as ``scipy.stats.rankdata(values, method="average")``.
    """
    x = np.asarray(values, dtype=np.float64)
    order = np.argsort(x, kind="mergesort")
    ranks = np.empty(len(x), dtype=np.float64)
    sorted_x = x[order]
    start = 0
    while start < len(x):
        stop = start + 1
        while stop < len(x) and sorted_x[stop] == sorted_x[start]:
            stop += 1
        ranks[order[start:stop]] = 0.5 * (start + 1 + stop)  # mean of ranks start+1 .. stop
        start = stop
    return ranks


def _max_violations(real: np.ndarray, wm: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Per-policy maximum violation cost; ``weight``: (N,) values whose |gap| is the cost."""
    wm_gt = wm[:, None] > wm[None, :]
    real_gt = real[:, None] > real[None, :]
    cost = np.abs(weight[:, None] - weight[None, :]) * (wm_gt != real_gt)
    return cost.max(axis=1)


def mmrv_simpler(real, wm, *, names=None) -> float:
    """Mean Maximum Rank Violation as SIMPLER defines it (Li et al. 2024, SIMPLER, Sec. 5).

    Follows ``mean_maximum_rank_violation(perf_sim, perf_real)`` in SIMPLER's
    ``simpler_env/utils/metrics.py``:
    ``MMRV = 1/N Σ_i max_j |real_i − real_j| · 1[(wm_i > wm_j) ≠ (real_i > real_j)]``
    (with max over an empty set = 0). Ties as described in the module docstring.

    ``real``, ``wm``: (N,) per-policy success rates (or any scores; the cost is
    measured in ``real``'s unit). Returns a float in [0, max_ij |real_i − real_j|]; lower is better.
    """
    _, r, w = align_policy_values(real, wm, names=names)
    return float(_max_violations(r, w, r).mean())


def mmrv_rank(real, wm, *, names=None) -> float:
    """MMRV on the rank vector — the form the OSCAR paper reports (Appendix "Metric definitions" (i)).

    The paper gives "MMRV on the seven-policy rank vector (range [0, 6])"
    without a formula. Our reading: SIMPLER's MMRV with each policy's value
    replaced by its rank, i.e.
    ``MMRV_rank = 1/N Σ_i max_j |R_i − R_j| · 1[(wm_i > wm_j) ≠ (real_i > real_j)]``
    with ``R`` the average ranks of ``real`` (:func:`average_ranks`). The
    violation test is unchanged (ranking preserves order and ties); only the
    cost becomes the real-rank distance, so the range is [0, :func:`mmrv_rank_max` (N)]
    (policy i's cost is at most its distance to the farther end of the ranking,
    max(i − 1, N − i); the reversed ranking reaches all these bounds at once:
    33/7 ≈ 4.714 for N = 7, where the paper states [0, 6]) and multiples of 1/N appear when there are no ties —
    consistent with the paper's 0.571 = 4/7, 0.714 = 5/7, 1.429 = 10/7.
    (The table cannot pin the reading down further: by exhaustive search over
    7-policy orders, MMRV_rank = 4/7 with Spearman ρ = 0.750, and 5/7 with
    0.679, are impossible when both come from the same rank vectors without ties
    real-side, so the paper's two columns were presumably computed from
    differently-derived scores.)

    ``real``, ``wm``: (N,) per-policy ranking scores, higher = better (success
    rates, BT scores or Elo). Returns a float in ranks; lower is better.
    """
    _, r, w = align_policy_values(real, wm, names=names)
    return float(_max_violations(r, w, average_ranks(r)).mean())


def mmrv_rank_max(n: int) -> float:
    """The largest value :func:`mmrv_rank` can take for ``n`` policies: ``1/n Σ_{i=1..n} max(i − 1, n − i)``.

    Policy i (real rank i, no ties) can at worst violate against the policy
    farthest from it in real rank, at distance max(i − 1, n − i); the reversed
    ranking makes every policy violate against every other, so all these
    bounds are reached together. Ties only shrink rank distances. 1 for n = 2,
    2.5 for n = 4, 33/7 ≈ 4.714 for n = 7; ≈ 3n/4 for large n.
    """
    n = int(n)
    if n < 2:
        raise MetricInputError("n", "value", "at least 2 policies", n)
    return sum(max(i - 1, n - i) for i in range(1, n + 1)) / n


def _pearson(x: np.ndarray, y: np.ndarray) -> float:
    # constant input: r is undefined. Test the values, not the centred sum of squares: the mean of
    # seven 0.1's is not exactly 0.1 in floating point, which would turn "undefined" into noise
    if len(x) < 2 or bool(np.all(x == x[0])) or bool(np.all(y == y[0])):
        return float("nan")
    xc, yc = x - x.mean(), y - y.mean()
    denom = math.sqrt(float(xc @ xc) * float(yc @ yc))
    if denom == 0.0:
        return float("nan")
    return float(np.clip(float(xc @ yc) / denom, -1.0, 1.0))


def pearson_r(real, wm, *, names=None) -> float:
    """Pearson correlation r between per-policy results (OSCAR Appendix "Metric definitions" (iii)).

    ``r = Σ (x − x̄)(y − ȳ) / sqrt(Σ (x − x̄)² Σ (y − ȳ)²)`` over the N policies,
    the same value as ``scipy.stats.pearsonr(real, wm).statistic``. The paper
    applies it to per-policy mean binary success rates. If either vector is
    constant r is undefined and NaN is returned (as scipy does).
    (SIMPLER's own ``pearson_correlation`` adds 1e-8 to the denominator and
    returns 1 when the centred vectors are equal; we keep the textbook value.)

    ``real``, ``wm``: (N,) numbers. Returns a float in [−1, 1] or NaN.
    """
    _, r, w = align_policy_values(real, wm, names=names)
    return _pearson(r, w)


def spearman_rho(real, wm, *, names=None) -> float:
    """Spearman ρ between per-policy rank vectors (OSCAR Appendix "Metric definitions" (ii)).

    Pearson r of the average ranks of ``real`` and ``wm`` — identical to
    ``scipy.stats.spearmanr(real, wm).statistic``, including ties; without ties
    it equals ``1 − 6 Σ d² / (N (N² − 1))``. NaN if either vector is constant.

    ``real``, ``wm``: (N,) ranking scores, higher = better. Returns a float in [−1, 1] or NaN.
    """
    _, r, w = align_policy_values(real, wm, names=names)
    return _pearson(average_ranks(r), average_ranks(w))


def _check_rates(values: np.ndarray, names, source: str) -> None:
    for n, v in zip(names, values):
        if not 0.0 <= v <= 1.0:
            raise MetricInputError(source, f"{n}", "a success rate in [0, 1] (a fraction, not a percentage)", v)


def sisr_delta(real, wm, *, names=None) -> float:
    """SISR_Δ: mean absolute success-rate difference, in percentage points (OSCAR Appendix (iv)).

    ``SISR_Δ = 100 · 1/N Σ_i |SR_real,i − SR_wm,i|``.

    ``real``, ``wm``: (N,) per-policy success rates as fractions in [0, 1].
    Returns a float in [0, 100] (pp); lower is better.
    """
    order, r, w = align_policy_values(real, wm, names=names)
    _check_rates(r, order, "real")
    _check_rates(w, order, "wm")
    return float(100.0 * np.abs(r - w).mean())


def success_rates(outcomes: Mapping, *, source: str = "outcomes") -> dict[str, float]:
    """Per-policy mean binary success: ``{policy: [0/1, ...]}`` → ``{policy: rate in [0, 1]}``.

    Each list holds one binary verdict (0/1 or False/True) per episode and must not be empty.
    """
    out = {}
    for name, episodes in outcomes.items():
        if isinstance(episodes, (str, bytes)) or not isinstance(episodes, (Sequence, np.ndarray)) or len(episodes) == 0:
            raise MetricInputError(source, f"{name}", "a non-empty list of 0/1 episode outcomes", repr(episodes))
        vals = []
        for k, e in enumerate(episodes):
            if isinstance(e, (bool, np.bool_)):
                e = int(e)
            if not isinstance(e, (int, np.integer, float, np.floating)) or e not in (0, 1):
                raise MetricInputError(source, f"{name}[{k}]", "0 or 1 (binary episode success)", repr(e))
            vals.append(float(e))
        out[str(name)] = float(np.mean(vals))
    return out


# --------------------------------------------------------------------------- #
# one-call comparison
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class PolicyComparison:
    """All rank-fidelity metrics for one world-model evaluation against the real one.

    ``mmrv`` is the paper's rank form (:func:`mmrv_rank`), ``mmrv_simpler``
    SIMPLER's success-rate form; ``spearman_rho`` and ``mmrv`` use the ranking
    scores named by ``ranked_by``; ``pearson_r``, ``sisr_delta_pp`` and
    ``mmrv_simpler`` use success rates.
    """

    policies: tuple[str, ...]
    real_success: np.ndarray
    wm_success: np.ndarray
    real_score: np.ndarray
    wm_score: np.ndarray
    ranked_by: dict
    mmrv: float
    mmrv_simpler: float
    spearman_rho: float
    pearson_r: float
    sisr_delta_pp: float

    def to_dict(self) -> dict:
        """JSON-ready dictionary (NaN → null)."""
        n = len(self.policies)
        real_rank = n + 1 - average_ranks(self.real_score)
        wm_rank = n + 1 - average_ranks(self.wm_score)
        return nan_to_none(
            {
                "n_policies": n,
                "ranked_by": dict(self.ranked_by),
                "metrics": {
                    "mmrv": self.mmrv,
                    "mmrv_simpler": self.mmrv_simpler,
                    "spearman_rho": self.spearman_rho,
                    "pearson_r": self.pearson_r,
                    "sisr_delta_pp": self.sisr_delta_pp,
                },
                "policies": [
                    {
                        "policy": p,
                        "real_success": float(self.real_success[k]),
                        "wm_success": float(self.wm_success[k]),
                        "real_score": float(self.real_score[k]),
                        "wm_score": float(self.wm_score[k]),
                        "real_rank": float(real_rank[k]),
                        "wm_rank": float(wm_rank[k]),
                    }
                    for k, p in enumerate(self.policies)
                ],
            }
        )

    def format_table(self) -> str:
        """Human-readable table: one row per policy (rank 1 = best), then the metrics."""
        d = self.to_dict()
        header = ("policy", "real SR", "wm SR", "real score", "wm score", "real rank", "wm rank")
        rows = [header] + [
            (
                p["policy"],
                f"{p['real_success']:.3f}",
                f"{p['wm_success']:.3f}",
                f"{p['real_score']:.4g}",
                f"{p['wm_score']:.4g}",
                f"{p['real_rank']:g}",
                f"{p['wm_rank']:g}",
            )
            for p in sorted(d["policies"], key=lambda p: p["real_rank"])
        ]
        widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
        lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
        m = d["metrics"]

        def f(v, fmt):
            return "n/a" if v is None else format(v, fmt)

        lines.append("")
        lines.append(f"ranked by: real={self.ranked_by['real']}, wm={self.ranked_by['wm']}")
        lines.append(
            f"MMRV (rank, range [0, {mmrv_rank_max(len(self.policies)):.3f}]) {f(m['mmrv'], '.3f')}   "
            f"MMRV (SIMPLER, SR gap) {f(m['mmrv_simpler'], '.3f')}   "
            f"Spearman rho {f(m['spearman_rho'], '+.3f')}   Pearson r {f(m['pearson_r'], '+.3f')}   "
            f"SISR_delta {f(m['sisr_delta_pp'], '.2f')} pp"
        )
        return "\n".join(lines)


def compare_policies(
    real_success,
    wm_success,
    *,
    real_score=None,
    wm_score=None,
    names=None,
    real_score_label: str = "score",
    wm_score_label: str = "score",
) -> PolicyComparison:
    """Every rank-fidelity metric of the paper's policy-evaluation table in one call.

    ``real_success``, ``wm_success``: per-policy success rates in [0, 1]
    (mappings by name, or sequences with ``names``). ``real_score`` /
    ``wm_score``: optional per-policy ranking scores (e.g. RoboArena Elo, or BT
    scores from world-model preferences), same policies; each defaults to its
    side's success rates. MMRV (rank form) and Spearman ρ use the ranking
    scores; Pearson r, SISR_Δ and SIMPLER's MMRV use the success rates.
    ``*_score_label`` names the given scores in ``ranked_by`` (e.g. ``"bradley_terry_elo"``).
    """
    order, rs, ws = align_policy_values(
        real_success, wm_success, names=names, real_name="real_success", wm_name="wm_success"
    )
    _check_rates(rs, order, "real_success")
    _check_rates(ws, order, "wm_success")
    keyed = isinstance(real_success, Mapping)

    def scores(given, fallback, side, label):
        if given is None:
            return fallback, "success_rate"
        ref = dict(zip(order, fallback)) if keyed else fallback
        _, _, vals = align_policy_values(ref, given, names=order, real_name=f"{side}_success", wm_name=f"{side}_score")
        return vals, label

    r_score, r_by = scores(real_score, rs, "real", real_score_label)
    w_score, w_by = scores(wm_score, ws, "wm", wm_score_label)
    return PolicyComparison(
        policies=order,
        real_success=rs,
        wm_success=ws,
        real_score=r_score,
        wm_score=w_score,
        ranked_by={"real": r_by, "wm": w_by},
        mmrv=mmrv_rank(r_score, w_score),
        mmrv_simpler=mmrv_simpler(rs, ws),
        spearman_rho=spearman_rho(r_score, w_score),
        pearson_r=pearson_r(rs, ws),
        sisr_delta_pp=sisr_delta(rs, ws),
    )
