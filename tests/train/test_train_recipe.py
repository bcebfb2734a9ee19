"""The recipe's units against answers known in advance: timestep law, dropout rate, mixing weights, window prior, flow."""

import math

import numpy as np
import pytest
import torch
from scipy import stats

from oscar_core.model.sampler import flow_sigmas
from oscar_core.train.flow import flow_inputs, flow_loss, sample_sigmas, shift_sigma, sigma_cdf
from oscar_core.train.sampling import StepPlanner, crossings, mixing_weights, trapezoid, window_prior


# ---------------------------------------------------------------------- timesteps
def test_timestep_sampler_matches_the_shifted_logit_normal():
    s = sample_sigmas(20000, torch.Generator().manual_seed(0), shift=5.0).numpy()
    assert ((s > 0) & (s < 1)).all()
    p = stats.kstest(s, np.vectorize(lambda x: sigma_cdf(x, 5.0))).pvalue
    assert p > 1e-3
    # the test can fail: the same draws against the law of another shift are rejected
    assert stats.kstest(s, np.vectorize(lambda x: sigma_cdf(x, 3.0))).pvalue < 1e-6
    # the analytic CDF is that of sigmoid(N(0,1)) pushed through the shift: its median is shift(0.5) = 5/6
    assert sigma_cdf(shift_sigma(0.5, 5.0), 5.0) == pytest.approx(0.5, abs=1e-12)


def test_shift_is_the_samplers_schedule_shift():
    u = torch.linspace(1, 0, 11, dtype=torch.float64)
    torch.testing.assert_close(shift_sigma(u, 5.0), flow_sigmas(10, 5.0))


# ---------------------------------------------------------------------- flow
def test_flow_inputs_follow_the_samplers_convention():
    g = torch.Generator().manual_seed(0)
    z0, eps = torch.randn(3, 4, 5, 2, 2, generator=g), torch.randn(3, 4, 5, 2, 2, generator=g)
    sigma = torch.tensor([0.1, 0.5, 0.9], dtype=torch.float64)
    fi = flow_inputs(z0, eps, sigma, cond_timestep=1e-4)
    s = sigma.float().view(3, 1, 1, 1, 1)
    torch.testing.assert_close(fi.x[:, :, 1:], ((1 - s) * z0 + s * eps)[:, :, 1:])
    assert torch.equal(fi.x[:, :, 0], z0[:, :, 0])  # the conditioning frame is clean
    assert torch.equal(fi.condition_mask[:, :, 0], torch.ones(3, 1, 2, 2))
    assert fi.condition_mask[:, :, 1:].abs().sum() == 0
    assert torch.allclose(fi.timestep[:, 0, 0], torch.full((3, 1, 1), 1e-4))
    torch.testing.assert_close(fi.timestep[:, 0, 1:, 0, 0], s.view(3, 1).expand(3, 4))
    # an exact velocity prediction takes one Euler step from sigma to 0 onto z0 (the sampler's update)
    torch.testing.assert_close((fi.x - s * fi.target)[:, :, 1:], z0[:, :, 1:])
    assert float(flow_loss(fi.target, fi)) == 0.0


def test_conditioning_frame_contributes_exactly_zero_loss():
    g = torch.Generator().manual_seed(1)
    z0, eps = torch.randn(2, 4, 3, 2, 2, generator=g), torch.randn(2, 4, 3, 2, 2, generator=g)
    fi = flow_inputs(z0, eps, torch.tensor([0.3, 0.7], dtype=torch.float64))
    pred = torch.randn(2, 4, 3, 2, 2, generator=g, requires_grad=True)
    loss = flow_loss(pred, fi)
    loss.backward()
    assert pred.grad[:, :, 0].abs().sum() == 0 and pred.grad[:, :, 1:].abs().sum() > 0
    wild = pred.detach().clone()
    wild[:, :, 0] += 1e6
    assert float(flow_loss(wild, fi)) == float(loss.detach())
    # the value is the MSE over frames 1.. (per sample, then averaged)
    want = ((pred.detach() - fi.target)[:, :, 1:] ** 2).mean()
    assert float(loss.detach()) == pytest.approx(float(want), rel=1e-6)


# ---------------------------------------------------------------------- mixing and dropout
def _clips(sources_frames, window=9):
    return [(src, n, np.full((n, 1), 0.9), None) for src, n in sources_frames]


def test_mixing_weights_closed_form_and_measured():
    w = mixing_weights({"big": 8000, "small": 1000}, temperature=3.0)
    assert w["big"] == pytest.approx(2 / 3) and w["small"] == pytest.approx(1 / 3)  # 8000^(1/3) = 20, 1000^(1/3) = 10
    planner = StepPlanner(_clips([("big", 4000), ("big", 4000), ("small", 1000)]), 9, seed=0, dropout=0.0)
    draws = [it.clip for step in range(400) for it in planner.plan(step, 16)]
    frac_small = np.mean(np.array(draws) == 2)
    sd = math.sqrt(w["small"] * (1 - w["small"]) / len(draws))
    assert abs(frac_small - 1 / 3) < 4 * sd
    # inside a source, clips are drawn by their number of window starts
    assert abs(np.mean(np.array(draws) == 0) - 1 / 3) < 4 * sd


def test_skeleton_dropout_rate():
    planner = StepPlanner(_clips([("a", 100)]), 9, seed=3, dropout=0.2)
    drops = np.array([it.drop for step in range(500) for it in planner.plan(step, 16)])
    sd = math.sqrt(0.2 * 0.8 / drops.size)
    assert abs(drops.mean() - 0.2) < 4 * sd
    assert not any(it.drop for it in StepPlanner(_clips([("a", 100)]), 9, dropout=0.0).plan(0, 64))


def test_plan_is_a_function_of_seed_and_step():
    p1 = StepPlanner(_clips([("a", 100), ("b", 50)]), 9, seed=5)
    p2 = StepPlanner(_clips([("a", 100), ("b", 50)]), 9, seed=5)
    assert p1.plan(7, 8) == p2.plan(7, 8)
    assert p1.plan(7, 8) != p1.plan(8, 8)
    items = p1.plan(0, 8)
    shares = [StepPlanner.rank_slice(items, r, 4) for r in range(4)]
    assert sum(shares, []) == items  # the ranks' shares partition the global batch
    with pytest.raises(ValueError, match="multiple of the 3 processes"):
        StepPlanner.rank_slice(items, 0, 3)


# ---------------------------------------------------------------------- window prior
def test_crossings_of_the_binary_signal():
    op = np.array([[0.9], [0.8], [0.4], [0.3], [0.6], [0.7]])
    assert crossings(op).tolist() == [2, 4]
    assert crossings(np.zeros((10, 0))).size == 0
    two = np.array([[0.9, 0.1], [0.9, 0.9], [0.1, 0.9]])
    assert crossings(two).tolist() == [1, 2]


def test_trapezoid_shape():
    w = trapezoid(np.arange(-1, 82), 81, 0.25)
    assert w[0] == 0 and w[-1] == 0  # outside the window
    assert w[1 + 40] == 1.0  # plateau in the middle
    assert np.all(np.diff(w[1:22]) > 0) and np.allclose(w[1:82], w[1:82][::-1])  # ramps, symmetric


def test_window_prior_biases_windows_toward_crossings():
    T, W, c = 250, 81, 100
    op = np.full((T, 1), 0.9)
    op[c:] = 0.1  # one grasp at frame 100
    p = window_prior(op, W)
    assert p.sum() == pytest.approx(1.0)
    rng = np.random.default_rng(0)
    starts = rng.choice(len(p), size=20000, p=p)
    contains = (starts <= c) & (c < starts + W)
    assert contains.mean() == 1.0  # every drawn window holds the crossing
    uniform_rate = np.mean([(s <= c < s + W) for s in range(T - W + 1)])
    assert uniform_rate < 0.5  # ... where a uniform start would hold it less than half of the time
    d = c - starts
    assert abs(d.mean() - (W - 1) / 2) < 1.0  # and centred in the window
    # closed form: P(start) ∝ trapezoid(c - start)
    want = trapezoid(c - np.arange(T - W + 1), W, 0.25)
    np.testing.assert_allclose(p, want / want.sum())


def test_window_prior_falls_back_to_uniform():
    p = window_prior(np.full((100, 1), 0.9), 81)
    np.testing.assert_allclose(p, np.full(20, 1 / 20))
    p = window_prior(np.zeros((100, 0)), 81)  # no gripper
    np.testing.assert_allclose(p, np.full(20, 1 / 20))
    with pytest.raises(ValueError, match="shorter than the window"):
        window_prior(np.zeros((50, 1)), 81)
    mixed = window_prior(np.r_[np.full((50, 1), 0.9), np.full((50, 1), 0.1)], 81, uniform=0.5)
    assert mixed.min() >= 0.5 / 20 - 1e-12


def test_window_prior_over_cached_starts_only():
    op = np.full((120, 1), 0.9)
    op[60:] = 0.1
    starts = np.array([0, 10, 39, 100 - 81 + 20])  # the windows a latent cache holds
    p = window_prior(op, 81, starts=starts)
    want = trapezoid(60 - starts, 81, 0.25)
    np.testing.assert_allclose(p, want / want.sum())
    planner = StepPlanner([("a", 120, op, starts)], 81, seed=0)
    drawn = {it.start for step in range(50) for it in planner.plan(step, 4)}
    assert drawn <= set(starts.tolist())
