"""Per-cell agreement, Cohen's κ and pair separation between a world model's verdicts and the truth, against values
worked out by hand, with their undefined cases in words."""

import numpy as np
import pytest

from oscar_core.metrics.cell_agreement import agreement_summary, cell_agreement, cohen_kappa, pair_separation


def test_kappa_of_a_worked_example():
    # 10 cells: truth 1 1 1 1 1 1 0 0 0 0, verdict 1 1 1 1 0 0 0 0 0 1
    # p_o = 7/10; truth rate 0.6, verdict rate 0.5; p_e = 0.6*0.5 + 0.4*0.5 = 0.5; kappa = (0.7 - 0.5) / 0.5 = 0.4
    real = np.array([1, 1, 1, 1, 1, 1, 0, 0, 0, 0], float)[:, None]
    wm = np.array([1, 1, 1, 1, 0, 0, 0, 0, 0, 1], float)[:, None]
    k, why = cohen_kappa(real, wm)
    assert k == pytest.approx(0.4) and why is None
    assert cell_agreement(real, wm) == pytest.approx(0.7)


def test_perfect_chance_and_inverse_agreement():
    real = np.array([[1, 0], [0, 1], [1, 1], [0, 0]], float)
    assert cohen_kappa(real, real)[0] == pytest.approx(1.0)
    assert cohen_kappa(real, 1 - real)[0] == pytest.approx(-1.0)
    const = np.ones_like(real)
    k, why = cohen_kappa(const, const)
    assert k is None and "every one of the 8 cells a success" in why


def test_seed_averages_vote_and_unjudged_cells_are_left_out():
    real = np.array([[1, 0], [1, np.nan]], float)
    wm = np.array([[0.5, 0.49], [np.nan, 1.0]], float)
    assert cell_agreement(real, wm) == 1.0  # only (0,0): 0.5 votes 1 and (0,1): 0.49 votes 0 are judged by both


def test_pair_separation_counts_only_sessions_the_truth_separates_and_the_direction():
    policies = ["exact", "never"]
    real = np.array([[1, 0], [1, 0], [1, 0], [0, 0]], float)
    wm = np.array([[1, 0], [1, 1], [0, 1], [1, 1]], float)  # right, same, swapped; the last session does not count
    frac, n, why = pair_separation(real, wm, 0, 1)
    assert (frac, n, why) == (pytest.approx(1 / 3), 3, None)
    none, n0, why0 = pair_separation(real[3:], wm[3:], 0, 1)
    assert none is None and n0 == 0 and "same outcome" in why0
    s = agreement_summary(real, wm, policies, pairs=[("exact", "never")], resamples=200)
    pair = s["pairs"]["exact vs never"]
    assert pair["separated"] == pytest.approx(1 / 3) and pair["sessions"] == 3
    lo, hi = pair["ci95"]
    assert 0.0 <= lo <= 1 / 3 <= hi <= 1.0


def test_summary_intervals_cover_the_estimate_and_one_session_says_why():
    rng = np.random.default_rng(0)
    real = (rng.uniform(size=(40, 4)) < [0.9, 0.6, 0.3, 0.05]).astype(float)
    wm = np.where(rng.uniform(size=real.shape) < 0.8, real, 1 - real)
    s = agreement_summary(real, wm, ["a", "b", "c", "d"], resamples=500)
    lo, hi = s["agreement_ci95"]
    assert lo <= s["agreement"] <= hi and hi - lo < 0.3
    klo, khi = s["kappa_ci95"]
    assert klo <= s["kappa"] <= khi
    assert s["per_policy_agreement"]["a"] == cell_agreement(real[:, 0], wm[:, 0])
    one = agreement_summary(real[:1], wm[:1], ["a", "b", "c", "d"])
    assert one["agreement_ci95"] is None and "1 session" in one["ci95_why"]
