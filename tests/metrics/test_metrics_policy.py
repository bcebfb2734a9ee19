"""Policy-evaluation metrics: rank fidelity (MMRV, rho, r, SISR_delta) and Bradley-Terry-Davidson."""

import itertools
import json
import math
import warnings

import numpy as np
import pytest
import scipy.stats as st
from scipy.optimize import minimize

from oscar_core.metrics import (
    BradleyTerryWarning,
    MetricInputError,
    average_ranks,
    compare_policies,
    fit_bradley_terry,
    mmrv_rank,
    mmrv_simpler,
    parse_preference,
    pearson_r,
    sisr_delta,
    spearman_rho,
    success_rates,
)


# --------------------------------------------------------------------------- #
# against scipy on random inputs
# --------------------------------------------------------------------------- #
def test_correlations_match_scipy_on_random_inputs_with_ties():
    rng = np.random.default_rng(0)
    for _ in range(300):
        n = int(rng.integers(2, 10))
        # coarse grid of rates -> frequent ties, sometimes constant vectors
        real = rng.integers(0, 5, n) / 4
        wm = rng.integers(0, 5, n) / 4
        assert np.allclose(average_ranks(real), st.rankdata(real, method="average"))
        constant = np.ptp(real) == 0 or np.ptp(wm) == 0
        if constant:
            assert math.isnan(pearson_r(real, wm)) and math.isnan(spearman_rho(real, wm))
            continue
        assert pearson_r(real, wm) == pytest.approx(st.pearsonr(real, wm).statistic, abs=1e-12)
        assert spearman_rho(real, wm) == pytest.approx(st.spearmanr(real, wm).statistic, abs=1e-12)


def test_correlations_match_scipy_on_continuous_scores():
    rng = np.random.default_rng(1)
    real, wm = rng.normal(size=7), rng.normal(size=7)
    assert pearson_r(real, wm) == pytest.approx(st.pearsonr(real, wm).statistic, abs=1e-12)
    assert spearman_rho(real, wm) == pytest.approx(st.spearmanr(real, wm).statistic, abs=1e-12)


def _mmrv_loops(real, wm, weight):
    # literal double loop of SIMPLER's definition (strict ">" on both sides)
    out = []
    for i in range(len(real)):
        v = 0.0
        for j in range(len(real)):
            if (wm[i] > wm[j]) != (real[i] > real[j]):
                v = max(v, abs(weight[i] - weight[j]))
        out.append(v)
    return float(np.mean(out))


def test_mmrv_matches_literal_definition_on_random_inputs():
    rng = np.random.default_rng(2)
    for _ in range(200):
        n = int(rng.integers(2, 9))
        real, wm = rng.integers(0, 4, n) / 3, rng.integers(0, 4, n) / 3
        assert mmrv_simpler(real, wm) == pytest.approx(_mmrv_loops(real, wm, real), abs=1e-12)
        assert mmrv_rank(real, wm) == pytest.approx(_mmrv_loops(real, wm, st.rankdata(real)), abs=1e-12)
        assert 0 <= mmrv_rank(real, wm) <= n - 1


# --------------------------------------------------------------------------- #
# hand-worked cases
# --------------------------------------------------------------------------- #
def test_mmrv_hand_worked():
    real = {"p0": 0.9, "p1": 0.5, "p2": 0.2}
    wm = {"p0": 0.4, "p1": 0.6, "p2": 0.1}
    # pair (p0, p1): wm says p1 > p0, real says p0 > p1 -> violation, SR gap |0.9 - 0.5| = 0.4
    # pairs (p0, p2), (p1, p2): same order in both -> no violation
    # per-policy max: p0 0.4, p1 0.4, p2 0   -> SIMPLER MMRV = 0.8 / 3
    assert mmrv_simpler(real, wm) == pytest.approx(0.8 / 3)
    # real ranks (ascending) p0=3, p1=2, p2=1; the p0/p1 violation costs |3 - 2| = 1
    # per-policy max: 1, 1, 0 -> rank MMRV = 2 / 3
    assert mmrv_rank(real, wm) == pytest.approx(2 / 3)
    # perfect agreement and full reversal
    assert mmrv_simpler(real, real) == 0 and mmrv_rank(real, real) == 0
    # reversed 3 policies: ranks 3,2,1 vs 1,2,3; each pair violates.
    # p0: max(|3-2|, |3-1|) = 2; p1: max(1, 1) = 1; p2: 2 -> (2 + 1 + 2) / 3
    assert mmrv_rank([3, 2, 1], [1, 2, 3]) == pytest.approx(5 / 3)
    # N = 2 reversed reaches the top of the range [0, N - 1]
    assert mmrv_rank([1, 0], [0, 1]) == 1.0


def test_mmrv_ties_follow_simpler():
    real = [0.8, 0.4, 0.4]
    wm = [0.5, 0.5, 0.3]
    # p0 vs p1: wm tie -> (0.5 > 0.5) = False, real 0.8 > 0.4 = True -> violation, gap 0.4
    # p1 vs p0: (0.5 > 0.5) = False, (0.4 > 0.8) = False -> no violation (tie counts for the better one only)
    # p1 vs p2: wm 0.5 > 0.3 True, real 0.4 > 0.4 False -> violation but real gap 0 -> cost 0
    # p2 vs p1: False, False -> none.   per-policy max: 0.4, 0, 0 -> 0.4 / 3
    assert mmrv_simpler(real, wm) == pytest.approx(0.4 / 3)
    # real average ranks (ascending): p0 = 3, p1 = p2 = 1.5; p0's violation costs |3 - 1.5| = 1.5
    # p1's violation against p2 costs |1.5 - 1.5| = 0 -> 1.5 / 3 = 0.5
    assert mmrv_rank(real, wm) == pytest.approx(0.5)


def test_spearman_pearson_sisr_hand_worked():
    # ranks of [1, 2, 2, 3] are [1, 2.5, 2.5, 4]; of [1, 2, 3, 4] are [1, 2, 3, 4]; both have mean 2.5
    # centred: [-1.5, 0, 0, 1.5] and [-1.5, -0.5, 0.5, 1.5]
    # sum xy = 2.25 + 2.25 = 4.5; sum x^2 = 4.5; sum y^2 = 5  -> rho = 4.5 / sqrt(22.5) = 3 / sqrt(10)
    assert spearman_rho([1, 2, 2, 3], [1, 2, 3, 4]) == pytest.approx(3 / math.sqrt(10))
    # 7 policies, two adjacent swaps: sum d^2 = 4 -> rho = 1 - 6 * 4 / (7 * 48) = 1 - 24 / 336
    real = [7, 6, 5, 4, 3, 2, 1]
    wm = [6, 7, 4, 5, 3, 2, 1]
    assert spearman_rho(real, wm) == pytest.approx(1 - 24 / 336)
    # each swap costs 1 rank for both policies involved: (1 + 1 + 1 + 1) / 7 = 4/7 (the paper's 0.571 granularity)
    assert mmrv_rank(real, wm) == pytest.approx(4 / 7)
    # pearson: x = [0, 1, 2], y = [0, 1, 1]; centred [-1, 0, 1] and [-2/3, 1/3, 1/3]
    # sum xy = 2/3 + 1/3 = 1; sum x^2 = 2; sum y^2 = 4/9 + 1/9 + 1/9 = 2/3 -> r = 1 / sqrt(4/3) = sqrt(3)/2
    assert pearson_r([0, 1, 2], [0, 1, 1]) == pytest.approx(math.sqrt(3) / 2)
    # SISR: |0.5 - 0.4| = 0.10, |0.2 - 0.25| = 0.05 -> mean 0.075 -> 7.5 pp
    assert sisr_delta({"a": 0.5, "b": 0.2}, {"a": 0.4, "b": 0.25}) == pytest.approx(7.5)


def test_mappings_align_by_name():
    real = {"a": 0.1, "b": 0.5, "c": 0.9}
    wm_same_order = {"a": 0.2, "b": 0.4, "c": 0.7}
    wm_shuffled = {"c": 0.7, "a": 0.2, "b": 0.4}
    for f in (mmrv_simpler, mmrv_rank, spearman_rho, pearson_r, sisr_delta):
        assert f(real, wm_same_order) == pytest.approx(f(real, wm_shuffled))
    assert success_rates({"a": [1, 0, 1, 1], "b": [False, True]}) == {"a": 0.75, "b": 0.5}


def test_compare_policies_report_and_json():
    real_sr = {"pi0": 0.6, "fast": 0.5, "bin": 0.2}
    wm_sr = {"pi0": 0.55, "fast": 0.3, "bin": 0.25}
    real_elo = {"pi0": 1650.0, "fast": 1550.0, "bin": 1300.0}
    wm_bt = {"pi0": 1600.0, "fast": 1450.0, "bin": 1460.0}
    rep = compare_policies(real_sr, wm_sr, real_score=real_elo, wm_score=wm_bt)
    assert rep.ranked_by == {"real": "score", "wm": "score"}
    assert rep.mmrv == pytest.approx(mmrv_rank(real_elo, wm_bt))
    assert rep.spearman_rho == pytest.approx(spearman_rho(real_elo, wm_bt))
    assert rep.pearson_r == pytest.approx(pearson_r(real_sr, wm_sr))
    assert rep.mmrv_simpler == pytest.approx(mmrv_simpler(real_sr, wm_sr))
    assert rep.sisr_delta_pp == pytest.approx(sisr_delta(real_sr, wm_sr))
    d = json.loads(json.dumps(rep.to_dict()))
    row = [p for p in d["policies"] if p["policy"] == "fast"][0]
    assert row["real_rank"] == 2 and row["wm_rank"] == 3
    table = rep.format_table()
    assert "MMRV" in table and "pi0" in table.splitlines()[1]
    # without scores both sides rank by success rate
    assert compare_policies(real_sr, wm_sr).ranked_by == {"real": "success_rate", "wm": "success_rate"}


# --------------------------------------------------------------------------- #
# errors
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize(
    "real, wm, kwargs, words",
    [
        ([0.5], [0.5], {}, ["at least 2 policies", "found 1"]),
        ([0.5, 0.2], [0.5, 0.2, 0.1], {}, ["wm", "length", "2 values", "3 values"]),
        ({"a": 0.1, "b": 0.2}, {"a": 0.1, "c": 0.2}, {}, ["policy names", "missing ['b']", "extra ['c']"]),
        ({"a": 0.1, "b": 0.2}, [0.1, 0.2], {}, ["wm", "type", "mapping"]),
        ([0.1, float("nan")], [0.1, 0.2], {}, ["real", "[1]", "finite"]),
        ([0.1, 0.2], [0.1, 0.2], {"names": ["x"]}, ["names", "2 names", "found 1"]),
        ([0.1, "high"], [0.1, 0.2], {}, ["real", "a number", "'high'"]),
    ],
)
def test_rank_fidelity_errors(real, wm, kwargs, words):
    with pytest.raises(MetricInputError) as exc:
        spearman_rho(real, wm, **kwargs)
    for w in words:
        assert w in str(exc.value)


def test_sisr_rejects_percentages():
    with pytest.raises(MetricInputError, match=r"wm: field 'b': expected a success rate in \[0, 1\]"):
        sisr_delta({"a": 0.5, "b": 0.2}, {"a": 0.4, "b": 25.0})
    with pytest.raises(MetricInputError, match="0 or 1"):
        success_rates({"a": [1, 2]})


# --------------------------------------------------------------------------- #
# Bradley-Terry with Davidson ties
# --------------------------------------------------------------------------- #
def _davidson_nll(theta, nu, prefs, names):
    # independent, explicit negative log-likelihood of the Davidson model
    idx = {n: k for k, n in enumerate(names)}
    total = 0.0
    for a, b, y in prefs:
        ta, tb = theta[idx[a]], theta[idx[b]]
        num = {2: math.exp(ta), 0: math.exp(tb), 1: 2 * nu * math.exp(0.5 * (ta + tb))}
        total -= math.log(num[y] / sum(num.values()))
    return total


def test_bt_hand_worked_two_policies():
    # A preferred 4 times, B once, 2 ties. With d = theta_A - theta_B and x = exp(d/2) the model is
    #   p_A = x / S, p_B = (1/x) / S, p_tie = 2 nu / S,  S = x + 1/x + 2 nu
    # two free parameters for three outcomes -> the MLE reproduces the frequencies 4/7, 1/7, 2/7:
    #   p_A / p_B = x^2 = 4        -> d = ln 4, centred theta = (+ln 2, -ln 2)
    #   p_tie / sqrt(p_A p_B) = 2 nu = (2/7) / (2/7) = 1 -> nu = 0.5
    prefs = [("A", "B", "a")] * 4 + [("A", "B", "b")] + [("A", "B", "tie")] * 2
    res = fit_bradley_terry(prefs)
    assert res.converged
    assert res.policies == ("A", "B")
    assert res.theta == pytest.approx([math.log(2), -math.log(2)], abs=1e-6)
    assert res.tie_nu == pytest.approx(0.5, abs=1e-6)
    # Elo = 200 theta + 1500
    assert res.elo == pytest.approx([1500 + 200 * math.log(2), 1500 - 200 * math.log(2)], abs=1e-4)
    assert res.ranking() == ["A", "B"]


def test_bt_tie_parameter():
    # equal policies: 3 wins each way and 2 ties. theta_A = theta_B, so
    #   p_tie = 2 nu / (2 + 2 nu) = nu / (1 + nu) = 2/8  ->  nu = 1/3
    prefs = [("A", "B", 2)] * 3 + [("B", "A", 2)] * 3 + [("A", "B", 1)] * 2
    res = fit_bradley_terry(prefs)
    assert res.theta == pytest.approx([0, 0], abs=1e-7)
    assert res.tie_nu == pytest.approx(1 / 3, abs=1e-6)
    # more ties -> larger nu; no ties -> nu driven to the lower clip exp(-10)
    more = fit_bradley_terry(prefs + [("A", "B", "tie")] * 6)
    assert more.tie_nu > res.tie_nu
    none = fit_bradley_terry([p for p in prefs if p[2] != 1])
    assert none.converged and none.theta == pytest.approx([0, 0], abs=1e-7)
    assert none.tie_nu == pytest.approx(math.exp(-10), rel=1e-6)


def _sample_prefs(theta, nu, n, rng, names):
    out = []
    for _ in range(n):
        i, j = rng.choice(len(theta), size=2, replace=False)
        w = np.array([math.exp(theta[i]), math.exp(theta[j]), 2 * nu * math.exp(0.5 * (theta[i] + theta[j]))])
        y = rng.choice([2, 0, 1], p=w / w.sum())
        out.append((names[i], names[j], int(y)))
    return out


def test_bt_matches_direct_mle_and_numeric_hessian():
    rng = np.random.default_rng(3)
    names = ["p0", "p1", "p2", "p3"]
    prefs = _sample_prefs([0.8, 0.1, -0.2, -0.7], 0.4, 300, rng, names)
    res = fit_bradley_terry(prefs, policies=names)

    # MLE by a general-purpose optimiser on the explicit likelihood (last theta fixed at 0)
    def f(x):
        return _davidson_nll(np.r_[x[:3], 0.0], math.exp(x[3]), prefs, names)

    opt = minimize(f, np.zeros(4), method="BFGS", options={"gtol": 1e-9})
    theta_ref = np.r_[opt.x[:3], 0.0]
    assert res.theta == pytest.approx(theta_ref - theta_ref.mean(), abs=1e-4)
    assert res.tie_nu == pytest.approx(math.exp(opt.x[3]), rel=1e-4)
    assert res.log_likelihood == pytest.approx(-opt.fun, abs=1e-6)

    # standard errors: centred inverse of a finite-difference Hessian of the same likelihood
    x0 = np.r_[res.theta[:3] - res.theta[3], math.log(res.tie_nu)]
    h, k = 1e-4, len(x0)
    H = np.zeros((k, k))
    for a in range(k):
        for b in range(k):
            ea, eb = np.eye(k)[a] * h, np.eye(k)[b] * h
            H[a, b] = (f(x0 + ea + eb) - f(x0 + ea - eb) - f(x0 - ea + eb) + f(x0 - ea - eb)) / (4 * h * h)
    cov = np.zeros((4, 4))
    cov[:3, :3] = np.linalg.inv(H)[:3, :3]
    C = np.eye(4) - 1 / 4
    assert res.std == pytest.approx(np.sqrt(np.diag(C @ cov @ C.T)), rel=1e-3)
    assert res.elo_std == pytest.approx(200 * res.std)


def test_bt_reference_policy_choice_does_not_matter():
    rng = np.random.default_rng(4)
    names = ["a", "b", "c", "d", "e"]
    prefs = _sample_prefs([0.5, 0.2, 0.0, -0.3, -0.4], 0.3, 400, rng, names)
    r1 = fit_bradley_terry(prefs, policies=names)
    r2 = fit_bradley_terry(prefs, policies=names[::-1])
    s1, s2 = r1.scores("theta"), r2.scores("theta")
    assert [s1[n] for n in names] == pytest.approx([s2[n] for n in names], abs=1e-6)
    assert dict(zip(r1.policies, r1.std))["c"] == pytest.approx(dict(zip(r2.policies, r2.std))["c"], rel=1e-5)
    # default order: first appearance in column a, then column b (RoboArena's pd.unique(concat([i, j])))
    assert fit_bradley_terry(
        [("x", "y", "a"), ("z", "x", "b"), ("y", "z", "tie"), ("w", "z", "a"), ("z", "w", "a"), ("y", "x", "a")]
    ).policies == ("x", "z", "y", "w")


def test_bt_recovers_known_strengths():
    rng = np.random.default_rng(5)
    names = ["pi0_flow", "pi0_fast", "pg_flow", "pg_fast", "pg_bin"]
    truth = np.array([1.0, 0.5, 0.0, -0.5, -1.0])
    prefs = [
        {"a": a, "b": b, "winner": {2: "a", 0: "b", 1: "tie"}[y], "session": k}
        for k, (a, b, y) in enumerate(_sample_prefs(truth, 0.3, 2000, rng, names))
    ]
    res = fit_bradley_terry(prefs)
    assert res.ranking() == names
    est = np.array([res.scores("theta")[n] for n in names])
    std = np.array([dict(zip(res.policies, res.std))[n] for n in names])
    assert np.all(np.abs(est - truth) < 4 * std)
    assert res.tie_nu == pytest.approx(0.3, abs=0.08)
    board = json.loads(json.dumps(res.to_dict()))["board"]
    assert [b["policy"] for b in board] == names and board[0]["elo"] > 1500 > board[-1]["elo"]
    assert "pi0_flow" in res.format_table().splitlines()[1]


def test_bt_warns_when_a_policy_never_loses():
    prefs = [("A", "B", "a")] * 3 + [("A", "C", "a")] * 2 + [("B", "C", "a"), ("C", "B", "a")]
    with pytest.warns(BradleyTerryWarning, match=r"infinite.*\['A'\]"):
        res = fit_bradley_terry(prefs, max_iters=30)
    assert res.ranking()[0] == "A"


@pytest.mark.parametrize(
    "prefs, kwargs, words",
    [
        (
            [("A", "B", "a"), ("A", "Q", "b")],
            {"policies": ["A", "B"]},
            ["preferences[1]", "field 'b'", "one of the policies ['A', 'B']", "'Q'"],
        ),
        ([("A", "A", "a")], {}, ["preferences[0]", "field 'b'", "a policy other than a='A'"]),
        ([("A", "B", "left")], {}, ["preferences[0]", "field 'winner'", "'left'"]),
        ([{"a": "A", "b": "B"}], {}, ["preferences[0]", "field 'winner'", "no such key"]),
        ([("A", "B", "a")], {"policies": ["A", "B", "C"]}, ["no comparisons for ['C']"]),
        ([("A", "B", "a"), ("C", "D", "tie")], {}, ["2 separate groups", "['A', 'B']", "['C', 'D']"]),
        ([], {}, ["at least 2 policies", "0 policies"]),
    ],
)
def test_bt_errors(prefs, kwargs, words):
    with pytest.raises(MetricInputError) as exc:
        fit_bradley_terry(prefs, **kwargs)
    for w in words:
        assert w in str(exc.value)


def test_parse_preference_forms():
    assert parse_preference(("a1", "b1", "A")).outcome == 2
    assert parse_preference({"a": "x", "b": "y", "preference": "TIE"}).outcome == 1
    assert parse_preference({"a": "x", "b": "y", "y": 0}).outcome == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert parse_preference(["x", "y", 2]).outcome == 2


def test_pearson_is_nan_for_constant_input_like_scipy():
    # the mean of seven 0.1's is not exactly 0.1: a centred-sum test would return float noise instead of NaN
    const, other = [0.1] * 7, [0.3, 0.2, 0.5, 0.1, 0.9, 0.4, 0.7]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # scipy's ConstantInputWarning
        assert math.isnan(st.pearsonr(other, const).statistic)
    assert math.isnan(pearson_r(other, const)) and math.isnan(pearson_r(const, other))
    assert math.isnan(spearman_rho(other, const))


def test_mmrv_rank_true_range_by_exhaustive_search():
    from oscar_core.metrics import mmrv_rank_max

    # every pair of score vectors over a small grid (ties included) for N = 2, 3; every pair of orders for N = 4, 5
    for n, grid in ((2, True), (3, True), (4, False), (5, False)):
        vectors = list(itertools.product(range(n), repeat=n)) if grid else list(itertools.permutations(range(n)))
        best = max(mmrv_rank(list(r), list(w)) for r in vectors for w in vectors)
        assert best == pytest.approx(mmrv_rank_max(n)), n
    # the paper's N = 7: 33/7, reached by the reversed ranking (the paper states [0, 6])
    assert mmrv_rank_max(7) == pytest.approx(33 / 7)
    assert mmrv_rank(list(range(7)), list(range(7))[::-1]) == pytest.approx(33 / 7)
    assert mmrv_rank_max(2) == 1.0


# --------------------------------------------------------------------------- #
# degenerate Bradley-Terry fits and the one ranking rule of eval policies / eval run
# --------------------------------------------------------------------------- #
def test_degenerate_fits_say_no_ranking_instead_of_numbers():
    import warnings

    from oscar_core.metrics.bradley_terry import PHI_BOUND, world_model_ranking

    all_ties = fit_bradley_terry([("a", "b", "tie"), ("b", "c", "tie"), ("a", "c", "tie")] * 3)
    assert all_ties.degenerate.startswith("every comparison is a tie")
    assert (
        all_ties.format_table().startswith("no ranking: every comparison is a tie")
        and "1500" not in all_ties.format_table()
    )
    assert all_ties.ranking_scores() is None and all_ties.to_dict()["degenerate"] == all_ties.degenerate
    scores, label, fallback = world_model_ranking(all_ties)
    assert (scores, label) == (None, "success_rate")
    assert fallback == (
        f"no Bradley-Terry ranking: {all_ties.degenerate}; the world model is ranked by its success rates"
    )
    # mostly ties, one decision: nu runs to its bound (the likelihood's maximum is at infinity)
    mostly = fit_bradley_terry(
        [("a", "b", "a"), ("a", "b", "tie"), ("b", "c", "tie"), ("c", "a", "tie")] * 2
        + [("b", "c", "b"), ("a", "c", "tie")]
    )
    assert mostly.tie_nu == pytest.approx(np.exp(PHI_BOUND)) and "optimiser's bound" in mostly.degenerate
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BradleyTerryWarning)
        # g beats b and m, nothing orders b against m: undetermined, whatever the optimiser's path says
        star = fit_bradley_terry([("g", "b", "a"), ("g", "m", "a")])
        chain = fit_bradley_terry([("g", "b", "a"), ("b", "m", "a"), ("g", "m", "a")])
    assert "leave the order of the groups" in star.degenerate and "['m']" in star.degenerate
    assert chain.degenerate is None and chain.ranking() == ["g", "b", "m"]  # a strict order is a ranking
    assert world_model_ranking(None, "no valid pairwise verdicts")[2].startswith(
        "no Bradley-Terry ranking: no valid pairwise verdicts;"
    )


def test_ranking_scores_tie_float_noise_but_keep_real_gaps():
    from oscar_core.metrics.bradley_terry import ELO_TIE_DECIMALS, BradleyTerryResult, world_model_ranking

    bt = fit_bradley_terry(
        [
            ("a", "b", "a"),
            ("a", "b", "a"),
            ("b", "a", "a"),
            ("a", "c", "a"),
            ("a", "c", "a"),
            ("c", "a", "a"),
            ("b", "c", "tie"),
            ("b", "c", "a"),
            ("c", "b", "a"),
        ]
    )
    assert bt.degenerate is None
    noisy = BradleyTerryResult(
        bt.policies,
        bt.theta + np.array([0.0, 3e-11, -3e-11]),
        bt.std,
        bt.tie_nu,
        bt.n_comparisons,
        bt.log_likelihood,
        bt.iterations,
        bt.converged,
    )
    scores, label, fallback = world_model_ranking(noisy)
    assert label == "bradley_terry_elo" and fallback is None
    assert scores["b"] == scores["c"]  # b and c are symmetric: equal up to noise -> tied ranks
    assert scores == {p: round(v, ELO_TIE_DECIMALS) for p, v in noisy.scores("elo").items()}
    assert spearman_rho({"a": 1.0, "b": 0.5, "c": 0.5}, scores) == pytest.approx(1.0)


def test_eval_policies_on_an_all_tie_board_states_the_fallback(tmp_path, capsys):
    import argparse
    import json

    from oscar_core.metrics import add_eval_parser

    (tmp_path / "real.json").write_text(json.dumps({"a": 0.9, "b": 0.5, "c": 0.2}))
    (tmp_path / "wm.json").write_text(json.dumps({"a": 0.8, "b": 0.6, "c": 0.2}))
    (tmp_path / "p.jsonl").write_text(
        "\n".join(json.dumps({"a": x, "b": y, "winner": "tie"}) for x, y in [("a", "b"), ("b", "c"), ("a", "c")] * 4)
    )
    parser = argparse.ArgumentParser(prog="oscar")
    add_eval_parser(parser.add_subparsers(dest="command", required=True))
    argv = [
        "eval",
        "policies",
        "--real",
        str(tmp_path / "real.json"),
        "--wm",
        str(tmp_path / "wm.json"),
        "--preferences",
        str(tmp_path / "p.jsonl"),
    ]
    args = parser.parse_args(argv)
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "no ranking: every comparison is a tie" in out and "1500.0" not in out
    assert "ranked by: real=success_rate, wm=success_rate" in out
    assert "no Bradley-Terry ranking: every comparison is a tie" in out
    args = parser.parse_args(argv + ["--json"])
    args.func(args)
    data = json.loads(capsys.readouterr().out)
    assert data["metrics"]["spearman_rho"] == pytest.approx(1.0) and data["ranked_by"]["wm"] == "success_rate"
    assert data["wm_ranking_fallback"].startswith("no Bradley-Terry ranking") and data["bradley_terry"]["degenerate"]
