"""Bradley–Terry scores with Davidson ties, fitted to pairwise preferences between policies.

This is how RoboArena's leaderboard ranks policies, and how ``oscar eval policies
--preferences`` and ``oscar eval run --pairwise`` rank the world model's side (see
:mod:`oscar_core.metrics.policy` for the rank-fidelity metrics that compare rankings).
Scores are shown as Elo = :data:`ELO_SCALE` · θ + :data:`ELO_SHIFT`.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from .common import MetricInputError, nan_to_none

__all__ = [
    "Preference",
    "parse_preference",
    "BradleyTerryResult",
    "BradleyTerryWarning",
    "fit_bradley_terry",
    "ELO_SCALE",
    "ELO_SHIFT",
    "ELO_TIE_DECIMALS",
    "PHI_BOUND",
    "world_model_ranking",
]

#: RoboArena's display transform of a Bradley–Terry score θ: Elo = 200·θ + 1500.
ELO_SCALE = 200.0
ELO_SHIFT = 1500.0
#: Elo scores are compared for ranking after rounding to this many decimals: scores equal up to the fit's
#: float noise (e.g. 1500.0000000055 against 1499.9999999986) are tied ranks, not an order drawn from the
#: last digits. ``oscar eval policies`` and ``oscar eval run`` both rank through :func:`world_model_ranking`.
ELO_TIE_DECIMALS = 6
#: The fit clips φ = log ν to [−PHI_BOUND, PHI_BOUND] (as RoboArena's backend does).
PHI_BOUND = 10.0


# --------------------------------------------------------------------------- #
# Bradley–Terry with Davidson ties
# --------------------------------------------------------------------------- #
class BradleyTerryWarning(RuntimeWarning):
    """The Bradley–Terry fit did not converge, or its maximum-likelihood scores do not exist."""


@dataclass(frozen=True)
class Preference:
    """One pairwise comparison: ``outcome`` is 2 if ``a`` was preferred, 0 if ``b`` was, 1 for a tie.

    (The integer coding is RoboArena's ``y``: "A" → 2, "TIE" → 1, "B" → 0.)
    """

    a: str
    b: str
    outcome: int
    #: where the record came from (e.g. ``prefs.jsonl:12``), for error messages
    where: str | None = field(default=None, compare=False)


_OUTCOMES = {"a": 2, "tie": 1, "b": 0, "2": 2, "1": 1, "0": 0}


def parse_preference(item, source: str = "preference") -> Preference:
    """Normalise one preference record.

    Accepted forms: a :class:`Preference`; a tuple/list ``(a, b, outcome)``; a
    dict ``{"a": name, "b": name, "winner": outcome}`` (the key may also be
    ``"preference"`` or ``"y"``; other keys such as ``"session"`` are ignored).
    ``outcome`` is ``"a"``, ``"b"`` or ``"tie"`` (any case), or RoboArena's
    integer ``y`` (2 = a preferred, 1 = tie, 0 = b preferred).
    """
    if isinstance(item, Preference):
        a, b, raw = item.a, item.b, item.outcome
        source = item.where or source
    elif isinstance(item, Mapping):
        for key in ("a", "b"):
            if key not in item:
                raise MetricInputError(source, key, "the name of a compared policy", "no such key")
        keys = [k for k in ("winner", "preference", "y") if k in item]
        if not keys:
            raise MetricInputError(source, "winner", '"a", "b" or "tie" (or "preference" / "y")', "no such key")
        a, b, raw = item["a"], item["b"], item[keys[0]]
    elif isinstance(item, (tuple, list)) and len(item) == 3:
        a, b, raw = item
    else:
        raise MetricInputError(source, "record", '(a, b, outcome) or {"a", "b", "winner"}', repr(item))
    for key, name in (("a", a), ("b", b)):
        if not isinstance(name, str) or not name:
            raise MetricInputError(source, key, "a non-empty policy name", repr(name))
    if a == b:
        raise MetricInputError(source, "b", f"a policy other than a={a!r}", repr(b))
    if isinstance(raw, (bool, np.bool_)):
        raise MetricInputError(source, "winner", '"a", "b", "tie" or 2/1/0', repr(raw))
    if isinstance(raw, (int, np.integer)):
        key = str(int(raw))
    else:
        key = raw.strip().lower() if isinstance(raw, str) else None
    if key not in _OUTCOMES:
        raise MetricInputError(source, "winner", '"a", "b", "tie" or 2/1/0', repr(raw))
    return Preference(a, b, _OUTCOMES[key], where=source)


@dataclass(frozen=True)
class BradleyTerryResult:
    """Bradley–Terry–Davidson scores of N policies.

    ``theta``: (N,) mean-centred log-strengths (RoboArena's ``score``),
    ``std``: (N,) their standard errors (RoboArena's ``std``), both in the
    order of ``policies``. ``elo = 200·θ + 1500`` and ``elo_std = 200·std``
    (RoboArena rounds them for display; we do not). ``tie_nu`` is Davidson's
    tie parameter ν.

    ``degenerate``: None for a fit whose scores rank the policies, else why they do
    not (every comparison a tie; ν at the optimiser's bound; groups of policies that no
    chain of preferences orders — their scores are infinite and their order comes from
    the optimiser's path; no convergence). A strict order of groups (everyone beats
    everyone below) is a ranking, although its scores are infinite (a warning says so). A degenerate result keeps its
    numbers for inspection, but :meth:`format_table` and :func:`world_model_ranking`
    show "no ranking: …" instead of them.
    """

    policies: tuple[str, ...]
    theta: np.ndarray
    std: np.ndarray
    tie_nu: float
    n_comparisons: int
    log_likelihood: float
    iterations: int
    converged: bool
    degenerate: str | None = None

    @property
    def elo(self) -> np.ndarray:
        return ELO_SCALE * self.theta + ELO_SHIFT

    @property
    def elo_std(self) -> np.ndarray:
        return ELO_SCALE * self.std

    def scores(self, kind: str = "elo") -> dict[str, float]:
        """``{policy: score}`` with ``kind`` "elo" or "theta"."""
        vals = {"elo": self.elo, "theta": self.theta}.get(kind)
        if vals is None:
            raise MetricInputError("kind", "kind", '"elo" or "theta"', repr(kind))
        return {p: float(v) for p, v in zip(self.policies, vals)}

    def ranking_scores(self) -> dict[str, float] | None:
        """``{policy: Elo}`` rounded to :data:`ELO_TIE_DECIMALS` for ranking, or None for a degenerate fit."""
        if self.degenerate is not None:
            return None
        return {p: round(v, ELO_TIE_DECIMALS) for p, v in self.scores("elo").items()}

    def ranking(self) -> list[str]:
        """Policies from strongest to weakest."""
        return [self.policies[k] for k in np.argsort(-self.theta, kind="mergesort")]

    def to_dict(self) -> dict:
        order = np.argsort(-self.theta, kind="mergesort")
        return nan_to_none(
            {
                "model": "bradley_terry_davidson",
                "tie_nu": self.tie_nu,
                "n_comparisons": self.n_comparisons,
                "log_likelihood": self.log_likelihood,
                "iterations": self.iterations,
                "converged": self.converged,
                "degenerate": self.degenerate,
                "board": [
                    {
                        "policy": self.policies[k],
                        "theta": float(self.theta[k]),
                        "std": float(self.std[k]),
                        "elo": float(self.elo[k]),
                        "elo_std": float(self.elo_std[k]),
                    }
                    for k in order
                ],
            }
        )

    def format_table(self) -> str:
        if self.degenerate is not None:
            return f"no ranking: {self.degenerate} ({self.n_comparisons} comparisons)"
        rows = [("policy", "Elo", "± std", "theta")] + [
            (b["policy"], f"{b['elo']:.1f}", f"{b['elo_std']:.1f}", f"{b['theta']:+.4f}")
            for b in self.to_dict()["board"]
        ]
        widths = [max(len(r[i]) for r in rows) for i in range(4)]
        lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
        lines.append(
            f"tie nu {self.tie_nu:.4f}   comparisons {self.n_comparisons}"
            + ("" if self.converged else "   (NOT converged)")
        )
        return "\n".join(lines)


def _components(n: int, edges: list[tuple[int, int]], strong: bool) -> tuple[int, np.ndarray]:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows = [e[0] for e in edges] or [0]
    cols = [e[1] for e in edges] or [0]
    data = np.ones(len(rows)) if edges else np.zeros(1)
    graph = coo_matrix((data, (rows, cols)), shape=(n, n))
    return connected_components(graph, directed=True, connection="strong" if strong else "weak")


def _unordered_groups(n_groups: int, labels: np.ndarray, edges: list[tuple[int, int]], names) -> list | None:
    """Two groups of policies (strongly connected components of the "beats or ties" graph) that no chain of
    preferences orders, or None when the groups form one strict order (then the ranking is determined even
    though the scores are infinite)."""
    reach = np.eye(n_groups, dtype=bool)
    for a, b in edges:
        reach[labels[a], labels[b]] = True
    for k in range(n_groups):  # transitive closure (Floyd–Warshall on booleans)
        reach |= reach[:, k : k + 1] & reach[k : k + 1, :]
    for g in range(n_groups):
        for h in range(g + 1, n_groups):
            if not reach[g, h] and not reach[h, g]:
                return [[names[k] for k in range(len(labels)) if labels[k] == c] for c in (g, h)]
    return None


def _policy_names(prefs: list[Preference], policies, source: str) -> list[str]:
    """The policies in fit order: ``policies`` as given (checked unique and covering every preference), or by
    default the order of first appearance in the ``a`` column and then the ``b`` column."""
    if policies is None:
        names: list[str] = []
        seen = set()
        for col in ("a", "b"):
            for p in prefs:
                name = getattr(p, col)
                if name not in seen:
                    seen.add(name)
                    names.append(name)
        return names
    names = [str(p) for p in policies]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise MetricInputError("policies", "policy names", "unique names", f"duplicates {dup}")
    known = set(names)
    for k, p in enumerate(prefs):
        for col in ("a", "b"):
            if getattr(p, col) not in known:
                raise MetricInputError(
                    p.where or f"{source}[{k}]", col, f"one of the policies {names}", repr(getattr(p, col))
                )
    return names


def _comparison_arrays(
    prefs: list[Preference], names: list[str], source: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(i_idx, j_idx, outcome)``, each (M,) int64 for M preferences: the indices into ``names`` of each
    comparison's ``a`` and ``b`` and its outcome (2 a preferred, 1 tie, 0 b preferred). Raises
    :class:`MetricInputError` for fewer than two policies or a listed policy with no comparisons."""
    n = len(names)
    if n < 2:
        raise MetricInputError(source, "policies", "comparisons between at least 2 policies", f"{n} policies {names}")
    idx = {name: k for k, name in enumerate(names)}
    i_idx = np.array([idx[p.a] for p in prefs], dtype=np.int64)
    j_idx = np.array([idx[p.b] for p in prefs], dtype=np.int64)
    outcome = np.array([p.outcome for p in prefs], dtype=np.int64)
    counts = np.bincount(i_idx, minlength=n) + np.bincount(j_idx, minlength=n)
    unused = [names[k] for k in range(n) if counts[k] == 0]
    if unused:
        raise MetricInputError(
            source, "policies", "at least one comparison for every listed policy", f"no comparisons for {unused}"
        )
    return i_idx, j_idx, outcome


def _beats_or_ties_graph(
    names: list[str], i_idx: np.ndarray, j_idx: np.ndarray, outcome: np.ndarray, source: str
) -> tuple[int, np.ndarray, list[tuple[int, int]]]:
    """Checks the comparison graph is connected (else :class:`MetricInputError`) and warns
    (:class:`BradleyTerryWarning`, attributed to the caller of :func:`fit_bradley_terry`) when the
    "beats or ties" graph is not strongly connected, i.e. the maximum-likelihood scores are infinite
    (Ford 1957, with ties as two-way links).

    Returns ``(n_strong, strong_labels, edges)``: the number of strongly connected groups, each policy's
    group label ((N,) int), and the graph's edges as (winner-or-tier, loser-or-tier) index pairs.
    """
    n = len(names)
    n_comp, labels = _components(n, list(zip(i_idx.tolist(), j_idx.tolist())), strong=False)
    if n_comp > 1:
        groups = [[names[k] for k in range(n) if labels[k] == c] for c in range(n_comp)]
        raise MetricInputError(
            source,
            "comparison graph",
            "every policy linked to every other through comparisons",
            f"{n_comp} separate groups {groups}",
        )
    edges = []
    for a, b, o in zip(i_idx.tolist(), j_idx.tolist(), outcome.tolist()):
        if o >= 1:
            edges.append((a, b))
        if o <= 1:
            edges.append((b, a))
    n_strong, strong_labels = _components(n, edges, strong=True)
    if n_strong > 1:
        groups = [[names[k] for k in range(n) if strong_labels[k] == c] for c in range(n_strong)]
        warnings.warn(
            f"{source}: some policies never lose (or never win) against the others, so their "
            f"maximum-likelihood Bradley-Terry scores are infinite; groups {groups}. The reported scores "
            f"grow with max_iters.",
            BradleyTerryWarning,
            stacklevel=3,
        )
    return n_strong, strong_labels, edges


def _davidson_objective(n: int, i_idx: np.ndarray, j_idx: np.ndarray, outcome: np.ndarray):
    """The Davidson negative log-likelihood of M comparisons among ``n`` policies, as a function of the
    free parameters ``x`` ((n,): θ_0 … θ_{n−2}, then φ = log ν; the last policy's θ is 0). The function
    returns ``(nll, grad, hess)``: a float in nats, (n,) and (n, n), each probability floored at 1e-12."""
    ref = n - 1
    free = np.r_[np.arange(n - 1), n]  # free θ's, then φ (index n in the full vector)
    k_rows = np.arange(len(outcome))
    A = np.zeros((len(outcome), n + 1))
    B = np.zeros((len(outcome), n + 1))
    A[k_rows, i_idx] = 1.0
    B[k_rows, j_idx] = 1.0
    T = 0.5 * A + 0.5 * B
    T[:, n] = 1.0
    V_obs = np.where((outcome == 2)[:, None], A, np.where((outcome == 0)[:, None], B, T))
    log_floor = math.log(1e-12)

    def nll_grad_hess(x: np.ndarray):
        theta = np.zeros(n)
        theta[:ref] = x[:ref]
        phi = x[-1]
        ti, tj = theta[i_idx], theta[j_idx]
        logits = np.stack([ti, tj, math.log(2.0) + phi + 0.5 * (ti + tj)], axis=1)
        m = logits.max(axis=1, keepdims=True)
        log_z = m[:, 0] + np.log(np.exp(logits - m).sum(axis=1))
        logp = logits - log_z[:, None]
        p = np.exp(logp)
        obs = np.where(outcome == 2, 0, np.where(outcome == 0, 1, 2))
        nll = float(-np.maximum(logp[k_rows, obs], log_floor).sum())
        p_i, p_j, p_t = p[:, 0:1], p[:, 1:2], p[:, 2:3]
        v_bar = p_i * A + p_j * B + p_t * T
        grad = (v_bar - V_obs).sum(axis=0)
        hess = A.T @ (p_i * A) + B.T @ (p_j * B) + T.T @ (p_t * T) - v_bar.T @ v_bar
        return nll, grad[free], hess[np.ix_(free, free)]

    return nll_grad_hess


def _newton_minimise(
    nll_grad_hess, n_params: int, n_comparisons: int, max_iters: int, tol: float, hess_ridge: float
) -> tuple[np.ndarray, int, bool]:
    """Newton steps with an Armijo line search on ``nll_grad_hess`` from θ = 0, ν = 0.5, φ (the last of the
    ``n_params`` parameters) clipped to ±:data:`PHI_BOUND`, as described in :func:`fit_bradley_terry`.
    Returns ``(params, iterations, converged)``: the (n_params,) parameters reached, the steps taken and
    whether a stopping test below ``tol`` was met."""
    params = np.zeros(n_params)
    params[-1] = math.log(0.5)
    eye = np.eye(n_params)
    converged, iterations = False, 0
    while iterations < max_iters:
        iterations += 1
        nll, grad, hess = nll_grad_hess(params)
        # φ held at its clip bound while the likelihood pushes it further out (e.g. no ties at all:
        # the MLE of ν is 0) — project that coordinate out, so the θ's still converge
        at_bound = (params[-1] <= -PHI_BOUND and grad[-1] > 0) or (params[-1] >= PHI_BOUND and grad[-1] < 0)
        if at_bound:
            grad = grad.copy()
            grad[-1] = 0.0
        if float(np.abs(grad).max()) < tol:
            converged = True
            break
        hess_reg = hess + hess_ridge * eye
        if at_bound:
            hess_reg[-1, :] = hess_reg[:, -1] = 0.0
            hess_reg[-1, -1] = 1.0
        try:
            step = np.linalg.solve(hess_reg, grad)
        except np.linalg.LinAlgError:
            step = np.linalg.lstsq(hess_reg, grad, rcond=None)[0]
        if not np.all(np.isfinite(step)):
            break
        step_inf = float(np.abs(step).max())
        if step_inf < tol:
            converged = True
            break
        directional = float(grad @ step)
        alpha, accepted = 1.0, False
        while alpha >= 1e-8:
            cand = params - alpha * step
            cand[-1] = float(np.clip(cand[-1], -PHI_BOUND, PHI_BOUND))
            if nll_grad_hess(cand)[0] <= nll - 1e-4 * alpha * directional:
                params, accepted = cand, True
                break
            alpha *= 0.5
        if not accepted:
            # no decrease possible: at the optimum to float precision, or stuck
            converged = float(np.abs(grad).max()) < 1e-6 * max(1, n_comparisons)
            break
        if alpha * step_inf < tol:
            converged = True
            break
    return params, iterations, converged


def _centred_scores(params: np.ndarray, hess: np.ndarray, hess_ridge: float) -> tuple[np.ndarray, np.ndarray]:
    """``(theta, std)``, each (N,): the mean-centred scores from the (N,) fitted parameters (N−1 free θ's
    then φ), and their standard errors from the (N, N) Hessian there (``C Σ Cᵀ``, see
    :func:`fit_bradley_terry`); a non-finite error is reported as 0."""
    n = len(params)
    ref = n - 1
    cov = np.linalg.pinv(hess + hess_ridge * np.eye(n), rcond=1e-12)
    theta = np.zeros(n)
    theta[:ref] = params[:ref]
    theta -= theta.mean()
    cov_ref = np.zeros((n, n))
    cov_ref[:ref, :ref] = cov[:ref, :ref]
    center = np.eye(n) - np.full((n, n), 1.0 / n)
    std = np.sqrt(np.clip(np.diag(center @ cov_ref @ center.T), 0.0, None))
    std = np.nan_to_num(std, nan=0.0, posinf=0.0, neginf=0.0)
    return theta, std


def _degenerate_reason(
    outcome: np.ndarray,
    phi: float,
    n_strong: int,
    strong_labels: np.ndarray,
    edges: list[tuple[int, int]],
    names: list[str],
    converged: bool,
    iterations: int,
) -> str | None:
    """Why the fitted scores do not rank the policies (a sentence), or None when they do."""
    if np.all(outcome == 1):
        return "every comparison is a tie, so the preferences do not order the policies"
    if phi >= PHI_BOUND:
        return (
            f"the tie parameter reached the optimiser's bound (nu = e^{PHI_BOUND:g}): almost every comparison is a tie"
        )
    if n_strong > 1 and (undetermined := _unordered_groups(n_strong, strong_labels, edges, names)):
        return (
            f"the preferences leave the order of the groups {undetermined} undetermined (and the "
            f"maximum-likelihood scores are infinite)"
        )
    if not converged and n_strong == 1:  # with infinite scores (a strict order of groups) it cannot converge
        return f"the fit did not converge in {iterations} steps"
    return None


def fit_bradley_terry(
    preferences,
    *,
    policies=None,
    max_iters: int = 200,
    tol: float = 1e-8,
    hess_ridge: float = 1e-6,
    source: str = "preferences",
) -> BradleyTerryResult:
    """Bradley–Terry scores with Davidson ties, fitted like RoboArena's leaderboard.

    Model (Davidson 1970), for a comparison of policies i and j::

        p(i preferred) = e^θi / Z,   p(j preferred) = e^θj / Z,   p(tie) = 2ν e^((θi+θj)/2) / Z

    with Z the sum of the three numerators. As in ``fit_bt_davidson`` of the
    RoboArena backend (``central_server.py``): the negative log-likelihood is
    minimised over (θ_0 … θ_{N−2}, φ = log ν) by Newton steps on the analytic
    gradient and observed Hessian (plus a ``hess_ridge`` · I ridge), with an
    Armijo backtracking line search (c = 1e-4, halving down to 1e-8) and φ
    clipped to [−10, 10] (one addition: while φ sits at a bound and the
    gradient points outwards — e.g. no ties at all, where the MLE of ν is 0 —
    φ is held there and the Newton step is taken in the θ's only, so the fit
    converges instead of spending ``max_iters`` on φ); the *last* policy's θ is fixed at 0; it starts at
    θ = 0, ν = 0.5 and stops after ``max_iters`` steps or when the gradient,
    the step or the accepted step falls below ``tol`` (∞-norm). The scores are
    then mean-centred, and their standard errors are the square roots of the
    diagonal of the centred inverse Hessian (pseudo-inverse, rcond 1e-12):
    ``C Σ Cᵀ`` with ``C = I − 11ᵀ/N`` and Σ the free-parameter covariance
    padded with a zero row/column for the fixed policy.

    ``preferences``: iterable of records accepted by :func:`parse_preference`.
    ``policies``: optional order of the policies (the last one is the fixed
    reference); by default the order of first appearance in the ``a`` column
    and then the ``b`` column, which is the order RoboArena's
    ``pd.unique(pd.concat([df.i, df.j]))`` gives. The fitted, centred scores
    do not depend on that choice.

    Raises :class:`MetricInputError` for a malformed record, a preference
    naming a policy not in ``policies``, a listed policy with no comparisons,
    fewer than two policies, or policies split into groups never compared with
    each other. Warns :class:`BradleyTerryWarning` when a group of policies
    never loses (or never wins) against the rest — the maximum-likelihood
    scores are then infinite and the reported ones grow with ``max_iters`` — or
    when the Newton iteration stops without converging.
    """
    prefs = [parse_preference(p, f"{source}[{k}]") for k, p in enumerate(preferences)]
    names = _policy_names(prefs, policies, source)
    i_idx, j_idx, outcome = _comparison_arrays(prefs, names, source)
    n_strong, strong_labels, edges = _beats_or_ties_graph(names, i_idx, j_idx, outcome, source)
    nll_grad_hess = _davidson_objective(len(names), i_idx, j_idx, outcome)
    params, iterations, converged = _newton_minimise(nll_grad_hess, len(names), len(prefs), max_iters, tol, hess_ridge)
    if not converged and n_strong == 1:
        warnings.warn(
            f"{source}: the Bradley-Terry Newton iteration stopped after {iterations} steps without "
            f"converging (tol={tol}).",
            BradleyTerryWarning,
            stacklevel=2,
        )
    final_nll, _, final_hess = nll_grad_hess(params)
    theta, std = _centred_scores(params, final_hess, hess_ridge)
    return BradleyTerryResult(
        policies=tuple(names),
        theta=theta,
        std=std,
        tie_nu=float(math.exp(params[-1])),
        n_comparisons=len(prefs),
        log_likelihood=-final_nll,
        iterations=iterations,
        converged=converged,
        degenerate=_degenerate_reason(
            outcome, float(params[-1]), n_strong, strong_labels, edges, names, converged, iterations
        ),
    )


def world_model_ranking(bt: BradleyTerryResult | None, no_fit_reason: str | None = None):
    """The world model's ranking scores from a Bradley–Terry fit, shared by ``eval policies`` and ``eval run``.

    Returns ``(scores, label, fallback)``: Elo rounded to :data:`ELO_TIE_DECIMALS` with label
    ``"bradley_terry_elo"`` and ``fallback`` None; or, when there is no fit (``no_fit_reason`` says
    why) or the fit is degenerate, ``(None, "success_rate", "no Bradley-Terry ranking: <why>; the world
    model is ranked by its success rates")`` — a sentence to show wherever the ranking is shown.
    """
    if bt is not None and bt.degenerate is None:
        return bt.ranking_scores(), "bradley_terry_elo", None
    why = bt.degenerate if bt is not None else (no_fit_reason or "no preferences")
    return None, "success_rate", f"no Bradley-Terry ranking: {why}; the world model is ranked by its success rates"
