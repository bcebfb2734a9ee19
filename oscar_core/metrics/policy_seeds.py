"""Policy evaluation over several rollout seeds, and how sure its ranking is over sessions.

A world model's verdict on one cell changes with the rollout's noise seed, so
one ``oscar eval run`` per seed over the same cells gives a success rate per
(session, policy) averaged over seeds. :func:`session_bootstrap` then resamples
the sessions with replacement and recomputes both sides' per-policy success
rates and Spearman ρ, which tells how much the ranking depends on which
sessions were drawn.

``python -m oscar_core.metrics.policy_seeds RUN [RUN ...]`` (:mod:`oscar_core.metrics.cli_policy_seeds`) reads the
``report.json`` of ``oscar eval run`` folders (one per seed, same manifest
cells) and prints the per-policy rates, ρ, its 95 % session interval,
P(ρ ≥ 0.8), Pearson r, MMRV and SISR_Δ.

Closed-loop runs (``oscar eval closed-loop``, one folder per noise seed: the manifest's ``seed``) are read the
same way with ``--truth SIM_RUN``, the same manifest run in a simulator (``--simulator toy``): a cell's real
outcome is the simulator's ``sim_success``, its world-model verdict the judge's ``success``, and a cell that
failed (a policy fault) counts as a failure, as the closed-loop report ranks it (:func:`closed_loop_cells`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .common import MetricInputError, percentile_interval
from .policy import mmrv_rank, pearson_r, sisr_delta, spearman_rho

__all__ = [
    "FIGURES",
    "cell_rates",
    "closed_loop_cells",
    "read_reports",
    "session_bootstrap",
    "session_bootstrap_figures",
    "session_intervals",
    "summarize_runs",
    "undefined_reasons",
]


def cell_rates(reports: list[dict]) -> tuple[list[str], list[str], np.ndarray, np.ndarray]:
    """(sessions, policies, real (S, P), wm (S, P)) from ``oscar eval run`` reports of the same cells.

    real: the cell's real success (0/1); wm: its world-model success averaged over the reports
    (cells a report did not judge are left out of that cell's mean; NaN when no report judged it).
    Raises ValueError when the reports disagree on a cell's real outcome (not the same manifest).
    """
    cells: dict[tuple[str, str], dict] = {}
    for rep in reports:
        for c in rep["cells"]:
            d = cells.setdefault((c["session"], c["policy"]), {"real": c["real_success"], "wm": []})
            if d["real"] != c["real_success"]:
                raise ValueError(
                    f"cell {c['cell']}: real success {c['real_success']} in one report and {d['real']} "
                    "in another; expected runs over the same manifest"
                )
            if c.get("wm_success") is not None:
                d["wm"].append(float(c["wm_success"]))
    sessions = sorted({s for s, _ in cells})
    policies = list(dict.fromkeys(p for _, p in cells))
    real = np.full((len(sessions), len(policies)), np.nan)
    wm = np.full_like(real, np.nan)
    for (s, p), d in cells.items():
        i, j = sessions.index(s), policies.index(p)
        real[i, j] = np.nan if d["real"] is None else float(d["real"])
        wm[i, j] = float(np.mean(d["wm"])) if d["wm"] else np.nan
    return sessions, policies, real, wm


def session_bootstrap(real: np.ndarray, wm: np.ndarray, resamples: int = 2000, seed: int = 0) -> np.ndarray:
    """(resamples,) Spearman ρ of the per-policy mean rates over sessions drawn with replacement.

    real, wm: (S, P) per-session success rates (NaN cells are left out of a policy's mean).
    A resample where either side's rates are all equal gives NaN (no ranking).
    """
    return session_bootstrap_figures(real, wm, resamples, seed, figures=("spearman_rho",))["spearman_rho"]


#: The figures :func:`session_bootstrap_figures` can resample: (function of (real rates, wm rates), needs a ranking
#: on both sides — NaN for a resample where either side's rates are all equal).
FIGURES = {
    "spearman_rho": (spearman_rho, True),
    "pearson_r": (pearson_r, True),
    "mmrv": (mmrv_rank, False),
    "sisr_delta_pp": (sisr_delta, False),
}


def session_bootstrap_figures(
    real: np.ndarray, wm: np.ndarray, resamples: int = 2000, seed: int = 0, figures=tuple(FIGURES)
) -> dict[str, np.ndarray]:
    """``{figure: (resamples,) values}`` of the :data:`FIGURES` named, each computed on the per-policy mean rates
    of the same sessions drawn with replacement (one draw per resample, shared by the figures).

    real, wm: (S, P) per-session success rates (NaN cells are left out of a policy's mean).
    """
    rng = np.random.default_rng(seed)
    out = {f: np.empty(int(resamples)) for f in figures}
    with np.errstate(invalid="ignore"):
        for k in range(int(resamples)):
            idx = rng.integers(0, real.shape[0], real.shape[0])
            r, w = np.nanmean(real[idx], 0), np.nanmean(wm[idx], 0)
            ranked = np.ptp(r) > 0 and np.ptp(w) > 0
            for f in figures:
                fn, needs_ranking = FIGURES[f]
                out[f][k] = fn(r, w) if ranked or not needs_ranking else np.nan
    return out


def session_intervals(real: np.ndarray, wm: np.ndarray, resamples: int = 2000, seed: int = 0) -> dict:
    """95 % percentile intervals over sessions (:func:`session_bootstrap_figures`) of every figure in
    :data:`FIGURES`: ``{figure: [lo, hi] or None}`` (None when no resample gave a value), plus ``resamples``
    and ``seed``."""
    boot = session_bootstrap_figures(real, wm, resamples, seed)
    out: dict = {}
    for f, vals in boot.items():
        out[f] = percentile_interval(vals)
    return {**out, "resamples": int(resamples), "seed": int(seed)}


def read_reports(folders) -> list[dict]:
    """The ``report.json`` of each ``oscar eval run`` folder; a MetricInputError naming the folder and what is wrong
    (no such folder, no report, unreadable JSON, no ``cells``) before anything is computed."""
    reports = []
    for folder in folders:
        path = Path(folder) / "report.json"
        if not path.is_file():
            found = "no such folder" if not Path(folder).exists() else "a folder without report.json"
            raise MetricInputError(str(folder), "report.json", "an `oscar eval run` output folder", found)
        try:
            report = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise MetricInputError(str(path), "JSON", "an `oscar eval run` report", f"unreadable ({exc})") from None
        if not isinstance(report, dict) or not isinstance(report.get("cells"), list):
            raise MetricInputError(
                str(path),
                "cells",
                "a list of judged cells",
                type(report.get("cells", None) if isinstance(report, dict) else report).__name__,
            )
        reports.append(report)
    return reports


CLOSED_LOOP = "oscar-closed-loop-report"


def closed_loop_cells(report: dict, truth: dict, source: str = "run") -> dict:
    """An ``oscar eval closed-loop`` report as the cells :func:`cell_rates` reads, its real outcomes from ``truth``.

    report: a world model's closed-loop report; truth: the same manifest's closed-loop report in a simulator.
    Per cell: ``real_success`` = the truth cell's ``sim_success`` (None where the simulator's cell failed);
    ``wm_success`` = the judge's verdict (0/1), 0 for a cell that failed, None for one not judged.
    A cell of ``report`` missing from ``truth`` is a :class:`MetricInputError` naming it.
    """
    real = {(c["session"], c["policy"]): c.get("sim_success") for c in truth["cells"]}
    cells = []
    for c in report["cells"]:
        key = (c["session"], c["policy"])
        if key not in real:
            raise MetricInputError(source, "cells", "cells the --truth run holds", f"{key[0]}/{key[1]} not in it")
        wm = 0 if c.get("status") == "failed" else c.get("success")
        cells.append(
            {
                "cell": f"{key[0]}/{key[1]}",
                "session": key[0],
                "policy": key[1],
                "real_success": real[key],
                "wm_success": None if wm is None else int(wm),
            }
        )
    return {"cells": cells}


def _with_truth(folders, reports: list[dict], truth) -> list[dict]:
    """Closed-loop reports converted against the ``truth`` run; eval-run reports unchanged (none may mix)."""
    kinds = {rep.get("format") == CLOSED_LOOP for rep in reports}
    if kinds == {False}:
        if truth is not None:
            raise MetricInputError(str(truth), "--truth", "closed-loop runs to compare with", "eval-run reports")
        return reports
    if len(kinds) > 1:
        raise MetricInputError(", ".join(map(str, folders)), "format", "runs of one kind", "eval-run and closed-loop")
    if truth is None:
        raise MetricInputError(
            str(folders[0]), "--truth", "the simulator's closed-loop run of the same manifest", "none"
        )
    (sim,) = read_reports([truth])
    if sim.get("format") != CLOSED_LOOP or not any(c.get("sim_success") is not None for c in sim["cells"]):
        raise MetricInputError(str(truth), "sim_success", "a closed-loop run in a simulator", "no simulator outcome")
    return [closed_loop_cells(rep, sim, str(f)) for f, rep in zip(folders, reports)]


def _equal(rates: np.ndarray) -> bool:
    finite = rates[np.isfinite(rates)]
    return finite.size > 0 and bool(np.all(finite == finite[0]))


def undefined_reasons(real: np.ndarray, wm: np.ndarray, n_sessions: int, n_finite: int, resamples: int) -> dict:
    """Why each figure of :func:`summarize_runs` would be undefined, as a sentence: ``{figure: reason}`` for
    ρ / r (fewer than two policies, or one side's rates all equal), the interval and P(ρ ≥ 0.8) (one session,
    or no resample with a defined ρ), MMRV and SISR_Δ (no policy). real, wm: (P,) per-policy rates."""
    p = int(np.isfinite(real).sum() if real.size else 0)
    if p < 2:
        corr = f"{p} policy with a real rate: a correlation needs at least 2"
    elif _equal(real):
        corr = f"the real rates are all equal ({real[np.isfinite(real)][0]:.3f}), so they rank nothing"
    elif _equal(wm):
        corr = f"the world model's rates are all equal ({wm[np.isfinite(wm)][0]:.3f}), so they rank nothing"
    else:
        corr = "a side has no rates"
    if n_sessions < 2:
        boot = f"{n_sessions} session: resampling the sessions needs at least 2"
    else:
        boot = f"no resample of the {n_sessions} sessions (of {resamples}) gave a defined rho: {corr}"
    return {
        "spearman_rho": corr,
        "pearson_r": corr,
        "spearman_ci95": boot,
        "p_rho_at_least_0_8": boot,
        "mmrv": "no policy with rates on both sides",
        "sisr_delta_pp": "no policy with rates on both sides",
    }


def default_pairs(policies: list[str], real_rates: np.ndarray) -> list[tuple[str, str]]:
    """The pair whose separation the summary reports when none is asked for: the truth's best and worst policy
    (none when fewer than two policies have a real rate or they are all equal)."""
    ok = [i for i in range(len(policies)) if np.isfinite(real_rates[i])]
    if len(ok) < 2 or _equal(real_rates):
        return []
    best = max(ok, key=lambda i: real_rates[i])
    worst = min(ok, key=lambda i: real_rates[i])
    return [(policies[best], policies[worst])]


def summarize_runs(folders, resamples: int = 2000, seed: int = 0, truth=None, pairs=None) -> dict:
    """The summary :func:`main` prints, as a dict, for ``oscar eval run`` output folders (one per seed), or for
    ``oscar eval closed-loop`` folders (one per noise seed) against ``truth``, the simulator's run of the same
    manifest (:func:`closed_loop_cells`).

    ``cells``: cell by cell (:func:`~oscar_core.metrics.cell_agreement.agreement_summary`), the agreement of the
    verdicts with the real outcomes, Cohen's κ and, for each (policy, policy) of ``pairs`` (default: the truth's best
    and worst, :func:`default_pairs`), how often the world model separates them the right way round.
    A figure that is undefined (ρ of equal rates, an interval over one session) is None and ``undefined`` maps
    it to a sentence saying why (:func:`undefined_reasons`). ``judged`` gives, per run, the cells with a world-model verdict out of its cells: a run with fewer is
    partial, and its missing cells leave those cells' seed averages on fewer seeds (``complete`` is False).
    """
    reports = _with_truth(folders, read_reports(folders), truth)
    try:
        sessions, policies, real, wm = cell_rates(reports)
    except (KeyError, ValueError) as exc:
        raise MetricInputError(
            ", ".join(map(str, folders)), "cells", "runs over the same manifest's cells", str(exc)
        ) from None
    judged = [[sum(c.get("wm_success") is not None for c in rep["cells"]), len(rep["cells"])] for rep in reports]
    r, w = np.nanmean(real, 0), np.nanmean(wm, 0)
    boot = session_bootstrap(real, wm, resamples, seed)
    # one session resampled is that session every time: no interval, however many resamples
    ok = boot[np.isfinite(boot)] if len(sessions) >= 2 else boot[:0]
    figures = {
        "spearman_rho": spearman_rho(r, w),
        "spearman_ci95": percentile_interval(ok),
        "p_rho_at_least_0_8": float(np.mean(ok >= 0.8)) if ok.size else None,
        "pearson_r": pearson_r(r, w),
        "mmrv": mmrv_rank(r, w),
        "sisr_delta_pp": sisr_delta(r, w),
    }
    why = undefined_reasons(r, w, len(sessions), ok.size, resamples)
    from .cell_agreement import agreement_summary

    pairs = default_pairs(policies, r) if pairs is None else [tuple(p) for p in pairs]
    cells = agreement_summary(real, wm, policies, pairs, resamples, seed)
    return {
        "runs": [str(f) for f in folders],
        "truth": None if truth is None else str(truth),
        "sessions": len(sessions),
        "policies": policies,
        "real_success": r.tolist(),
        "wm_success": w.tolist(),
        # an undefined figure is None (never NaN), and ``undefined`` says why
        **{k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in figures.items()},
        "undefined": {
            k: why[k] for k, v in figures.items() if v is None or (isinstance(v, float) and not np.isfinite(v))
        },
        "cells": cells,
        "judged": judged,
        "complete": all(j == n for j, n in judged),
        "resamples": resamples,
        "seed": seed,
    }


if __name__ == "__main__":
    # ``python -m oscar_core.metrics.policy_seeds`` runs the command module (parsing and printing live there; it
    # imports this module's functions, so it is run by name rather than imported back from here)
    import runpy

    runpy.run_module("oscar_core.metrics.cli_policy_seeds", run_name="__main__", alter_sys=True)
