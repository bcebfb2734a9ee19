"""A plugin's default pose: trajectories may leave out the joints it covers."""

import warnings

import numpy as np
import pytest

from oscar_core import Camera, DefaultPoseWarning, JointLimitWarning, Trajectory, get_embodiment, render_skeleton_video
from oscar_core.errors import PluginError, TrajectoryError


def toyarm_class(pose, **attrs):
    from oscar_toyarm import ToyArm

    return type("PosedToyArm", (ToyArm,), {"name": "posed_toyarm", "default_pose": pose, **attrs})


@pytest.fixture(scope="module")
def toy():
    from oscar_toyarm import ToyArm

    return ToyArm()


def full_traj(emb, T=5, seed=0):
    rng = np.random.default_rng(seed)
    lo, hi = emb.tree.limits()
    keep = [i for i, n in enumerate(emb.tree.joint_names) if n in emb.joint_names]
    q = lo[keep] + rng.uniform(0.2, 0.8, (T, len(keep))) * (hi[keep] - lo[keep])
    g = np.full((T, len(emb.grippers)), np.mean(emb.grippers[0].signal_range)) if emb.grippers else None
    return Trajectory(emb.joint_names, q, 10.0, gripper=g)


def drop(traj, names):
    keep = [i for i, n in enumerate(traj.joint_names) if n not in names]
    return traj.replace(joint_names=tuple(traj.joint_names[i] for i in keep), q=traj.q[:, keep])


def test_missing_joints_are_filled_from_the_default_pose_and_reported(toy):
    j0, j1 = toy.joint_names[0], toy.joint_names[-1]
    emb = toyarm_class({j0: 0.25, j1: -0.5})()
    full = full_traj(emb)
    partial = drop(full, {j0, j1})
    with pytest.warns(DefaultPoseWarning) as rec:
        checked = emb.check_trajectory(partial)
    w = [r.message for r in rec if isinstance(r.message, DefaultPoseWarning)][0]
    assert w.joints == (j0, j1) and w.values == {j0: 0.25, j1: -0.5}
    assert j0 in str(w) and j1 in str(w) and "default pose" in str(w)
    assert checked.joint_names == emb.joint_names
    expected = full.q.copy()
    expected[:, 0], expected[:, -1] = 0.25, -0.5
    np.testing.assert_array_equal(checked.q, expected)
    # the same result for callers, without a warning
    filled_traj, filled = emb.fill_default_pose(partial)
    assert filled == {j0: 0.25, j1: -0.5} and filled_traj.q.shape == full.q.shape


def test_a_complete_trajectory_uses_no_default_and_does_not_warn(toy):
    emb = toyarm_class({toy.joint_names[0]: 0.25})()
    full = full_traj(emb)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DefaultPoseWarning)
        checked = emb.check_trajectory(full)
    np.testing.assert_array_equal(checked.q, full.q)  # the trajectory's own values win
    assert emb.fill_default_pose(full)[1] == {}


def test_missing_joints_without_a_default_are_an_error_naming_them(toy):
    j0, j1 = toy.joint_names[0], toy.joint_names[1]
    emb = toyarm_class({j0: 0.0})()
    with pytest.raises(TrajectoryError) as e:
        emb.check_trajectory(drop(full_traj(emb), {j0, j1}))
    msg = str(e.value)
    assert f"missing ['{j1}']" in msg and "no default pose" in msg
    with pytest.raises(TrajectoryError, match=f"missing \\['{j0}'\\]"):
        toy.check_trajectory(drop(full_traj(toy), {j0}))  # no default pose at all


@pytest.mark.parametrize(
    "pose, problem",
    [
        ({"shoulder_pan": float("nan")}, "expected a finite number"),
        ({"shoulder_pan": "0"}, "expected a finite number"),
        ({"shoulder_pan": True}, "expected a finite number"),
        ([("shoulder_pan", 0.0)], "expected a mapping"),
    ],
)
def test_bad_default_pose_breaks_the_contract_at_class_level(pose, problem):
    cls = toyarm_class(pose)
    assert any(problem in p for p in cls.class_problems()), cls.class_problems()
    with pytest.raises(PluginError, match="default_pose"):
        cls()


def test_default_pose_names_and_limits_are_checked_against_the_urdf(toy):
    lo, hi = toy.tree.limits()
    j = toy.joint_names[0]
    upper = hi[list(toy.tree.joint_names).index(j)]
    driven = toy.grippers[0].joint
    assert driven is not None  # the toy arm's gripper drives a finger joint
    for pose, problem in (
        ({"no_such_joint": 0.0}, "expected a joint of the trajectory order"),
        ({driven: 0.0}, "expected a joint of the trajectory order"),
        ({j: upper + 0.5}, "within the joint's limits"),
    ):
        with pytest.raises(PluginError) as e:
            toyarm_class(pose)()
        assert problem in str(e.value) and "default_pose" in str(e.value)


def test_agibot_arm_only_trajectory_renders_as_with_its_zero_waist_and_head():
    emb = get_embodiment("agibot_g1")
    assert set(emb.default_pose) == {"idx01_body_joint1", "idx02_body_joint2", "idx11_head_joint1", "idx12_head_joint2"}
    from oscar_core import load_camera, load_trajectory

    full = load_trajectory(emb.example_trajectory).time_slice(0, 3)
    zeroed = full.replace(q=np.where(np.isin(np.array(full.joint_names), list(emb.default_pose)), 0.0, full.q))
    arms_only = drop(full, set(emb.default_pose))
    cam = load_camera(emb.example_camera)
    static = Camera(cam.intrinsics, _front_view())  # a static outside view
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JointLimitWarning)
        a = render_skeleton_video(emb, zeroed, static, (128, 96))
        with pytest.warns(DefaultPoseWarning, match="idx11_head_joint1"):
            b = render_skeleton_video(emb, arms_only, static, (128, 96))
    assert a.any() and np.array_equal(a, b)


def _front_view():
    from oscar_core import look_at

    return look_at([2.5, 0.0, 1.2], [0.0, 0.0, 1.0])
