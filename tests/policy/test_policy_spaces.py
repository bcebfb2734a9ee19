"""The policy protocol's checks and the action-space adapters against answers known in advance."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from oscar_core.plugin.registry import get_embodiment
from oscar_core.policy.ik import EndEffectorIK
from oscar_core.policy.loading import load_policy
from oscar_core.policy.protocol import (
    DROID_KEYS,
    PolicyFault,
    PolicySpec,
    PolicySpecError,
    absurd_bounds,
    call_policy,
    check_answer,
)
from oscar_core.policy.spaces import ActionAdapter, resample, resample_joints


@pytest.fixture(scope="module")
def franka():
    return get_embodiment("franka")


@pytest.fixture(scope="module")
def kuka():
    return get_embodiment("kuka")


def _mid(adapter):
    return (adapter.lo + adapter.hi) / 2


# ---------------------------------------------------------------------------------------------------- protocol


def test_spec_defaults_are_droids_and_bad_fields_are_named():
    spec = PolicySpec.from_dict({"name": "pi05", "policy": "ws://127.0.0.1:8000"})
    assert spec.action_space == "joint_velocity" and spec.control_hz == 15.0 and spec.actions_per_call == 8
    assert dict(spec.keys) == dict(DROID_KEYS)
    assert spec.keys["image"] == "observation/exterior_image_1_left"
    with pytest.raises(PolicySpecError, match="field 'action_space': expected one of .* found 'torques'"):
        PolicySpec.from_dict({"name": "x", "policy": "m:a", "action_space": "torques"}, source="m.json")
    with pytest.raises(PolicySpecError, match="m.json: field 'actions_per_call'"):
        PolicySpec.from_dict({"name": "x", "policy": "m:a", "actions_per_call": 0}, source="m.json")
    with pytest.raises(PolicySpecError, match="unknown keys"):
        PolicySpec.from_dict({"name": "x", "policy": "m:a", "hz": 3})


def test_check_answer_accepts_good_and_names_each_fault():
    good = check_answer({"actions": np.zeros((10, 8), np.float32)}, width=8, min_horizon=8)
    assert good.shape == (10, 8) and good.dtype == np.float64
    cases = [
        ([1, 2], "expected a dict"),
        ({"act": 1}, "found keys"),
        ({"actions": np.zeros((10, 7))}, r"shape \(H, 8\), found \(10, 7\)"),
        ({"actions": np.zeros((4, 8))}, "at least 8 rows"),
        ({"actions": np.array([["a"] * 8] * 8)}, "dtype"),
        ({"actions": np.full((8, 8), np.nan)}, "finite values, found nan at row 0, column 0"),
        ({"actions": np.full((8, 8), np.inf)}, "finite"),
    ]
    for answer, match in cases:
        with pytest.raises(PolicyFault, match=match):
            check_answer(answer, width=8, min_horizon=8)
    lo, hi = np.full(7, -1.0), np.full(7, 1.0)
    bounds = absurd_bounds("joint_position", lo, hi, 15.0)
    ok = np.zeros((8, 8))
    ok[:, 0] = 2.9  # outside the limits but within one range of them: a clip, not absurd
    check_answer({"actions": ok}, width=8, min_horizon=8, bounds=bounds)
    ok[3, 0] = 3.5  # more than one range (2) beyond the upper limit
    with pytest.raises(PolicyFault, match="row 3"):
        check_answer({"actions": ok}, width=8, min_horizon=8, bounds=bounds)


def test_call_policy_timeout_and_exception():
    class Slow:
        def infer(self, obs):
            time.sleep(2.0)
            return {"actions": np.zeros((1, 2))}

    class Broken:
        def infer(self, obs):
            raise RuntimeError("out of memory\nmore text")

    t0 = time.perf_counter()
    with pytest.raises(PolicyFault, match="within 0.2 s"):
        call_policy(Slow(), {}, 0.2)
    assert time.perf_counter() - t0 < 1.5
    with pytest.raises(PolicyFault, match="infer raised RuntimeError: out of memory$"):
        call_policy(Broken(), {}, 5.0)
    answer, seconds = call_policy(load_policy("numpy:zeros_like"), np.ones(3), 5.0)  # a function is wrapped
    assert np.array_equal(answer, np.zeros(3)) and seconds >= 0


def test_load_policy_errors_name_the_source():
    with pytest.raises(PolicySpecError, match="no_such_module_xyz:attr"):
        load_policy("no_such_module_xyz:attr")
    with pytest.raises(PolicySpecError, match="entry point"):
        load_policy("not-an-installed-policy")


# ---------------------------------------------------------------------------------------------------- spaces


def test_constant_velocity_integrates_to_a_line(franka):
    ad = ActionAdapter(franka, "joint_velocity", control_hz=15.0)
    q0 = _mid(ad)
    v = np.linspace(-0.3, 0.3, 7)
    acts = np.concatenate([np.tile(v, (12, 1)), np.zeros((12, 1))], axis=1)
    res = ad.apply(acts, q0)
    t = np.arange(1, 13)[:, None] / 15.0
    np.testing.assert_allclose(res.q, q0 + v * t, atol=1e-12)
    assert res.clipped == 0 and np.isnan(res.ik_position_error).all()


def test_deltas_sum_and_absolute_is_taken(franka):
    ad = ActionAdapter(franka, "joint_delta")
    q0 = _mid(ad)
    d = np.random.default_rng(0).normal(0, 0.02, (9, 7))
    res = ad.apply(np.concatenate([d, np.ones((9, 1))], axis=1), q0)
    np.testing.assert_allclose(res.q, q0 + np.cumsum(d, axis=0), atol=1e-12)
    assert np.all(res.closure == 1.0)
    ab = ActionAdapter(franka, "joint_position")
    target = q0 + 0.1
    res = ab.apply(np.concatenate([np.tile(target, (3, 1)), np.zeros((3, 1))], axis=1), q0)
    np.testing.assert_allclose(res.q, np.tile(target, (3, 1)))


def test_limits_are_enforced_and_clips_counted(franka):
    ad = ActionAdapter(franka, "joint_velocity", control_hz=10.0)
    q0 = ad.hi - 0.05  # 0.05 rad under every upper limit
    acts = np.zeros((4, 8))
    acts[:, 0] = 1.0  # 0.1 rad per action on joint 0: the first action already passes the limit
    res = ad.apply(acts, q0)
    assert res.clipped == 4
    assert res.q[:, 0].max() == ad.hi[0]
    np.testing.assert_allclose(res.q[:, 1:], np.tile(q0[1:], (4, 1)))
    g = np.zeros((2, 8))
    g[:, -1] = [1.4, 0.3]  # a gripper closure above 1 is clipped and counted
    res = ad.apply(g, _mid(ad))
    assert res.clipped == 1 and list(res.closure) == [1.0, 0.3]
    binary = ActionAdapter(franka, "joint_velocity", gripper="binary").apply(g, _mid(ad))
    assert list(binary.closure) == [1.0, 0.0] and binary.clipped == 0


@pytest.mark.parametrize("name", ["franka", "kuka"])
def test_ik_round_trip_through_fk_under_1mm(name, request):
    emb = request.getfixturevalue(name)
    ik = EndEffectorIK(emb)
    rng = np.random.default_rng(1)
    worst_p = worst_r = 0.0
    for _ in range(12):
        q_true = ik.lo + rng.uniform(0.15, 0.85, len(ik.lo)) * (ik.hi - ik.lo)
        T = ik.pose(q_true)
        seed = np.clip(q_true + rng.normal(0, 0.15, len(q_true)), ik.lo, ik.hi)
        res = ik.solve(seed, T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec())
        back = ik.pose(res.q)  # an independent FK call on the answer
        worst_p = max(worst_p, float(np.linalg.norm(back[:3, 3] - T[:3, 3])))
        worst_r = max(worst_r, float(Rotation.from_matrix(back[:3, :3] @ T[:3, :3].T).magnitude()))
        assert res.position_error == pytest.approx(np.linalg.norm(back[:3, 3] - T[:3, 3]), abs=1e-9)
    assert worst_p < 1e-3 and worst_r < 1e-3


def test_ee_pose_adapter_records_the_residual(franka):
    ad = ActionAdapter(franka, "ee_pose")
    q0 = _mid(ad)
    T = ad.ik.pose(q0 + 0.1)
    row = np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec(), [0.0]])
    res = ad.apply(np.stack([row, row]), q0)
    assert np.all(res.ik_position_error < 1e-3)
    np.testing.assert_allclose(ad.ik.pose(res.q[0])[:3, 3], T[:3, 3], atol=1e-3)
    far = row.copy()
    far[:3] = [5.0, 0.0, 0.0]  # out of reach: solved as near as the arm goes, the residual says how far
    res = ad.apply(far[None], q0)
    assert res.ik_position_error[0] > 3.0


def test_ee_delta_moves_by_the_delta(kuka):
    ad = ActionAdapter(kuka, "ee_position_delta")
    q0 = _mid(ad) + np.array([0.2, 0.5, 0.1, -1.0, 0.1, 0.6, 0.0])  # bent: away from the straight-up singularity
    p0 = ad.ik.pose(q0)[:3, 3]
    step = np.array([0.01, -0.02, 0.015])
    res = ad.apply(np.tile(np.append(step, 0.0), (3, 1)), q0)
    reached = ad.ik.pose(res.q)[:, :3, 3]
    np.testing.assert_allclose(reached, p0 + np.arange(1, 4)[:, None] * step, atol=1e-3)


def test_resample_15hz_to_model_fps():
    hz, fps = 15.0, 10.0
    times = np.arange(0, 31) / hz  # knots over 2 s
    slope = np.array([0.5, -1.0])
    q = times[:, None] * slope + [0.1, 0.2]
    closure = (times >= 1.0).astype(float)  # closes at t = 1 s exactly
    at = np.arange(0, 21) / fps
    qs, cs = resample(times, q, closure, at)
    np.testing.assert_allclose(qs, at[:, None] * slope + [0.1, 0.2], atol=1e-12)  # a line stays that line
    assert list(cs) == [0.0] * 10 + [1.0] * 11
    # a sine sampled at 15 Hz and read at 10 fps: within the linear-interpolation bound (h² / 8 · max |f''|)
    f = np.sin(2 * np.pi * 0.5 * times)[:, None]
    got, _ = resample(times, f, closure, at)
    bound = (1 / hz) ** 2 / 8 * (2 * np.pi * 0.5) ** 2
    assert np.abs(got[:, 0] - np.sin(2 * np.pi * 0.5 * at)).max() <= bound + 1e-12


def test_resampling_against_analytic_trajectories():
    t = np.arange(31) / 15.0  # 2 s at 15 Hz
    lin = np.stack([0.3 * t - 1.0, -2.0 * t], axis=1)
    out, at = resample_joints(lin, t, 16.0)
    assert len(at) == 33 and at[-1] == pytest.approx(2.0)  # every 1/16 s within [0, 2]
    np.testing.assert_allclose(out, np.stack([0.3 * at - 1.0, -2.0 * at], axis=1), atol=1e-12)  # linear: exact
    sine = np.sin(3.0 * t)[:, None]
    out, at = resample_joints(sine, t, 16.0)
    # linear interpolation error <= h^2 / 8 * max|f''| = (1/15)^2 / 8 * 9
    bound = (1 / 15) ** 2 / 8 * 9
    err = np.abs(out[:, 0] - np.sin(3.0 * at)).max()
    assert err <= bound and err > bound / 10
    out, at = resample_joints(sine, t, 4.0)  # fewer frames: 0, 0.25, ..., 2.0
    np.testing.assert_allclose(at, np.arange(9) / 4.0)
    np.testing.assert_allclose(out[::4, 0], np.sin(3.0 * at[::4]), atol=1e-15)  # on knots (0, 1, 2 s): exact
    out, at = resample_joints(np.zeros((31, 0)), t, 4.0)  # no columns: the grid alone
    assert out.shape == (9, 0) and len(at) == 9
    from oscar_core.evaluation import roboarena

    assert roboarena.resample_joints is resample_joints  # the name RoboArena's conversion used keeps working


def test_ee_delta_rotation_is_composed_in_the_base_frame(franka):
    """An ``ee_delta`` row (dxyz, drotvec): the new orientation is Rot(drotvec) · R, the rotation about the base
    frame's axes (docs/closed-loop.md), not R · Rot(drotvec) (about the end-effector's own axes)."""
    ad = ActionAdapter(franka, "ee_delta")
    q0 = _mid(ad) + np.array([0.3, 0.2, -0.2, -0.4, 0.3, 0.5, 0.4])  # a pose whose frame is far from the base's
    T0 = ad.ik.pose(q0)
    dr = np.array([0.0, 0.0, 0.2])  # 0.2 rad about the base's z
    dp = np.array([0.01, 0.0, -0.01])
    res = ad.apply(np.concatenate([dp, dr, [0.0]])[None], q0)
    T1 = ad.ik.pose(res.q[0])
    base = Rotation.from_rotvec(dr).as_matrix() @ T0[:3, :3]
    body = T0[:3, :3] @ Rotation.from_rotvec(dr).as_matrix()
    assert Rotation.from_matrix(body @ base.T).magnitude() > 0.05  # the two readings differ on this pose
    assert Rotation.from_matrix(T1[:3, :3] @ base.T).magnitude() < 1e-3
    np.testing.assert_allclose(T1[:3, 3], T0[:3, 3] + dp, atol=1e-3)
    assert res.ik_position_error[0] < 1e-3 and res.ik_rotation_error[0] < 1e-3


def test_ik_restarts_keep_the_lowest_residual_solve(franka, monkeypatch):
    """A first solve that ends far away is repeated from fixed configurations; the solve kept is the one with the
    smallest residual, whichever restart it came from (here the second of four, the later ones worse)."""
    ik = EndEffectorIK(franka)
    residuals = iter([(0.5, 0.0), (0.2, 0.0), (0.01, 0.002), (0.3, 0.0), (0.05, 0.0)])
    from oscar_core.policy.ik import IKResult

    calls = []

    def fake(q0, position, rotvec=None):
        ep, er = next(residuals)
        calls.append(ep)
        return IKResult(np.full(len(ik.lo), float(len(calls))), ep, er, 10)

    monkeypatch.setattr(ik, "_solve", fake)
    best = ik.solve(_mid(ik), np.zeros(3), restarts=4)
    assert len(calls) == 5  # none reached 1 mm: every restart ran
    assert (best.position_error, best.rotation_error) == (0.01, 0.002) and best.q[0] == 3.0

    # and on the real solver: the kept answer is the best of the solves it ran, checked by FK
    ik = EndEffectorIK(franka)
    far = np.array([0.9, 0.6, 0.2])  # beyond the arm's reach: every solve ends away from it
    got = []
    real = EndEffectorIK._solve.__get__(ik)
    monkeypatch.setattr(ik, "_solve", lambda *a, **k: got.append(real(*a, **k)) or got[-1])
    best = ik.solve(_mid(ik) + 0.3, far, restarts=4)
    assert len(got) == 5
    assert best.position_error == min(r.position_error for r in got)
    assert best.position_error == pytest.approx(np.linalg.norm(ik.pose(best.q)[:3, 3] - far), abs=1e-9)
