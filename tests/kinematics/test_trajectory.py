"""Trajectory files and their validation against an embodiment."""

import sys

import numpy as np
import pytest
from _paths import REPO

from oscar_core import JointLimitWarning, Trajectory, load_trajectory, save_trajectory
from oscar_core.errors import OutputPathError, TrajectoryError

sys.path.insert(0, str(REPO / "examples" / "oscar-toyarm"))
from oscar_toyarm import ToyArm

ARM = ("base_yaw", "shoulder", "elbow", "wrist_pitch")


@pytest.fixture(scope="module")
def toyarm():
    return ToyArm()


def make(T=10, names=ARM, **kw):
    kw.setdefault("gripper", np.full((T, 1), 0.04))
    return Trajectory(names, np.zeros((T, len(names))), fps=10.0, **kw)


def test_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    base = np.tile(np.eye(4), (5, 1, 1))
    base[:, :3, 3] = rng.normal(size=(5, 3))
    traj = Trajectory(
        ARM,
        rng.normal(size=(5, 4)),
        fps=29.97,
        gripper=rng.uniform(0, 0.08, (5, 1)),
        gripper_names=("gripper",),
        base_pose=base,
        timestamps=np.arange(5) / 29.97,
    )
    path = save_trajectory(traj, tmp_path / "t.npz")
    back = load_trajectory(path)
    assert back.joint_names == ARM and back.fps == pytest.approx(29.97) and back.gripper_names == ("gripper",)
    for field in ("q", "gripper", "base_pose", "timestamps"):
        np.testing.assert_array_equal(getattr(back, field), getattr(traj, field))
    assert [p.name for p in tmp_path.iterdir()] == ["t.npz"]  # no temp file left


def test_reorders_joints_by_name(toyarm):
    q = np.arange(12.0).reshape(3, 4) / 10
    traj = Trajectory(ARM[::-1], q, fps=5, gripper=np.zeros((3, 1)))
    checked = toyarm.check_trajectory(traj)
    assert checked.joint_names == ARM
    np.testing.assert_array_equal(checked.q, q[:, ::-1])


@pytest.mark.parametrize(
    "kwargs, field, fragment",
    [
        (dict(names=ARM, q=np.zeros((5, 3))), "q", "shape (T, 4)"),
        (dict(names=ARM, q=np.zeros((0, 4))), "q", "at least one frame"),
        (dict(names=ARM, q=np.where(np.eye(5, 4) > 0, np.nan, 0.0)), "q", "nan at frame 0, joint 'base_yaw'"),
        (dict(names=ARM, q=np.full((5, 4), np.inf)), "q", "inf at frame 0"),
        (dict(names=ARM + ("base_yaw",), q=np.zeros((5, 5))), "joint_names", "duplicates"),
        (dict(names=ARM, q=np.zeros((5, 4)), fps=0), "fps", "positive"),
        (dict(names=ARM, q=np.zeros((5, 4)), gripper=np.zeros((4, 1))), "gripper", "shape (5, G)"),
        (dict(names=ARM, q=np.zeros((5, 4)), base_pose=np.zeros((5, 4, 4))), "base_pose", "rigid"),
        (dict(names=ARM, q=np.zeros((5, 4)), base_pose=np.zeros((5, 3, 4))), "base_pose", "(5, 4, 4)"),
    ],
)
def test_bad_trajectory_fields(kwargs, field, fragment):
    names, q = kwargs.pop("names"), kwargs.pop("q")
    kwargs.setdefault("fps", 10)
    with pytest.raises(TrajectoryError) as info:
        Trajectory(names, q, source="bad.npz", **kwargs)
    msg = str(info.value)
    assert f"bad.npz: field '{field}'" in msg and fragment in msg, msg


def test_unknown_and_missing_joint_names(toyarm):
    traj = make(names=("base_yaw", "shoulder", "elbow", "wrist_roll"))
    with pytest.raises(TrajectoryError) as info:
        toyarm.check_trajectory(traj)
    msg = str(info.value)
    assert "unknown ['wrist_roll']" in msg and "missing ['wrist_pitch']" in msg and "'toyarm'" in msg


def test_wrong_joint_count(toyarm):
    with pytest.raises(TrajectoryError, match=r"expected the 4 joints of 'toyarm'.*found 3 names"):
        toyarm.check_trajectory(make(names=ARM[:3]))


def test_gripper_checks(toyarm):
    with pytest.raises(TrajectoryError, match=r"field 'gripper': expected shape \(T, 1\)"):
        toyarm.check_trajectory(make(gripper=np.zeros((10, 2))))
    with pytest.raises(TrajectoryError, match=r"gripper\[gripper\].*\[0, 0.08\].*0.5 at frame 0"):
        toyarm.frames(toyarm.check_trajectory(make(gripper=np.full((10, 1), 0.5))))
    with pytest.raises(TrajectoryError, match="gripper_names"):
        toyarm.check_trajectory(make(gripper_names=("claw",)))


def test_limits_warn_but_render(toyarm):
    q = np.zeros((6, 4))
    q[2:4, 1] = 2.0  # shoulder limit is 1.6
    traj = Trajectory(ARM, q, fps=10, gripper=np.full((6, 1), 0.04), source="wild.npz")
    with pytest.warns(
        JointLimitWarning, match=r"wild.npz: joint 'shoulder' is beyond its limits \[-1.6, 1.6\] in 2 frames"
    ):
        checked = toyarm.check_trajectory(traj)
    assert toyarm.frames(checked).points.shape == (6, 8, 3)


def _write_npz(path, **arrays):
    np.savez(path, **arrays)
    return path


def test_bad_files(tmp_path):
    with pytest.raises(TrajectoryError, match="nope.npz.*no such file"):
        load_trajectory(tmp_path / "nope.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(TrajectoryError, match="junk.npz.*NumPy .npz"):
        load_trajectory(junk)
    p = _write_npz(tmp_path / "extra.npz", joint_names=np.array(ARM), q=np.zeros((2, 4)), fps=1.0, gripers=np.zeros(2))
    with pytest.raises(TrajectoryError, match=r"extra.npz: field 'gripers'.*unknown fields \['gripers'\]"):
        load_trajectory(p)
    p = _write_npz(tmp_path / "noq.npz", joint_names=np.array(ARM), fps=1.0)
    with pytest.raises(TrajectoryError, match="noq.npz: field 'q': expected a required field, found missing"):
        load_trajectory(p)
    p = _write_npz(tmp_path / "obj.npz", joint_names=np.array(ARM, dtype=object), q=np.zeros((2, 4)), fps=1.0)
    with pytest.raises(TrajectoryError, match="obj.npz.*no pickled objects"):
        load_trajectory(p)


def test_save_into_missing_folder(tmp_path):
    with pytest.raises(OutputPathError, match="does not exist"):
        save_trajectory(make(), tmp_path / "missing" / "t.npz")


def test_time_slice_cuts_every_per_frame_field():
    T = 6
    base = np.tile(np.eye(4), (T, 1, 1))
    base[:, 0, 3] = np.arange(T)
    traj = Trajectory(
        ARM,
        np.arange(T * 4.0).reshape(T, 4),
        fps=10,
        gripper=np.full((T, 1), 0.04),
        base_pose=base,
        timestamps=np.arange(T) / 10,
        keypoints=np.zeros((T, 2, 3)),
    )
    part = traj.time_slice(2, 4)
    assert len(part) == 2 and part.q[0, 0] == 8.0 and part.base_pose[0, 0, 3] == 2.0
    assert part.gripper.shape == (2, 1) and part.timestamps.shape == (2,) and part.keypoints.shape == (2, 2, 3)
