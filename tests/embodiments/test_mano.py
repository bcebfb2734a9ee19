"""The human-hand embodiment: topology, keypoint trajectories, cameras, flexion, missing hands."""

import sys

import numpy as np
import pytest
from _paths import REPO

from oscar_core import (
    Camera,
    Intrinsics,
    Trajectory,
    get_embodiment,
    load_camera,
    load_trajectory,
    render_skeleton_video,
    save_trajectory,
)
from oscar_core.camera import look_at
from oscar_core.errors import TrajectoryError
from oscar_core.render.skeleton_video import project_skeleton
from oscar_embodiments.mano import (
    SMPLX_MISSING,
    Mano,
    egocentric_camera,
    hand_openness,
    to_camera_frame,
    trajectory_from_keypoints,
    trajectory_from_mano,
)
from oscar_embodiments.mano.flexion import R_FIST, hold_missing
from oscar_embodiments.mano.synthetic import hand_keypoints, place, rotation
from oscar_embodiments.mano.topology import (
    COLORS,
    EDGES,
    FINGERTIP_VERTICES,
    GROUPS,
    KEYPOINT_NAMES,
    MANO_JOINT_NAMES,
    MANO_TO_KEYPOINTS,
    POINT_NAMES,
)

SIZE = (256, 144)


@pytest.fixture(scope="module")
def mano():
    return get_embodiment("mano")


@pytest.fixture(scope="module")
def example(mano):
    return mano.check_trajectory(load_trajectory(mano.example_trajectory)), load_camera(mano.example_camera)


def two_hands(T=3, curl=0.0):
    """(T, 2, 21, 3) flat hands 35 cm in front of an identity camera, left on the left."""
    kp = np.empty((T, 2, 21, 3))
    for h, (side, x) in enumerate((("left", -0.1), ("right", 0.1))):
        R = np.stack([[0, -0.6, 0.8], [1.0 if side == "right" else -1.0, 0, 0], [0, -0.8, -0.6]], axis=1)
        R[:, 1] = np.cross(R[:, 2], R[:, 0])
        kp[:, h] = place(hand_keypoints(curl, side=side), R, [x, 0.05, 0.3])
    return kp


# ---- topology ---------------------------------------------------------------------------


def test_keypoint_layout_and_mano_reordering():
    assert len(KEYPOINT_NAMES) == 21 and KEYPOINT_NAMES[0] == "wrist"
    assert KEYPOINT_NAMES[1:5] == ("thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip")
    assert KEYPOINT_NAMES[17:] == ("pinky_mcp", "pinky_pip", "pinky_dip", "pinky_tip")
    # smplx's 16 joints, then the tips thumb, index, middle, ring, pinky (indices 16..20)
    expected = [0, 13, 14, 15, 16, 1, 2, 3, 17, 4, 5, 6, 18, 10, 11, 12, 19, 7, 8, 9, 20]
    assert list(MANO_TO_KEYPOINTS) == expected
    assert MANO_JOINT_NAMES[13:] == ("thumb_cmc", "thumb_mcp", "thumb_ip")
    assert FINGERTIP_VERTICES == {"thumb": 744, "index": 320, "middle": 443, "ring": 554, "pinky": 671}


def test_skeleton_bones_groups_and_colours(mano):
    assert mano.skeleton.links == POINT_NAMES and len(POINT_NAMES) == 42
    assert POINT_NAMES[0] == "left_wrist" and POINT_NAMES[21] == "right_wrist"
    assert len(EDGES) == 40
    # each finger: wrist -> 4 points; no edge joins the two hands
    drawn = mano.edge_index()
    assert drawn.shape == (40, 2)
    assert all((a < 21) == (b < 21) for a, b in drawn)
    pts, edges = mano.colors()
    assert pts.shape == (42, 3) and edges.shape == (40, 3)
    left = {tuple(c) for c in pts[:21]}
    right = {tuple(c) for c in pts[21:]}
    assert len(left) == 6 and len(right) == 6 and not left & right  # wrist + 5 fingers per hand, distinct hands
    assert set(GROUPS) == set(COLORS)
    assert mano.problems() == [] and not mano.uses_kinematic_tree() and mano.joint_names == ()


def test_listing_says_what_the_mano_parameter_path_needs(mano, monkeypatch):
    assert "oscar-wm[mano]" in mano.description
    assert mano.info()["mano_parameters"].startswith("available")
    monkeypatch.setitem(sys.modules, "smplx", None)  # import smplx now fails
    info = mano.info()
    assert info["mano_parameters"] == SMPLX_MISSING and info["keypoints"] == 42


# ---- trajectories -------------------------------------------------------------------------


def test_keypoint_trajectory_round_trip_and_file_without_joints(tmp_path):
    kp = two_hands(4)
    kp[2, 1] = np.nan  # right hand missing in frame 2
    traj = trajectory_from_keypoints(kp, fps=30.0, timestamps=np.arange(4) / 30)
    assert traj.joint_names == () and traj.q.shape == (4, 0) and traj.keypoints.shape == (4, 42, 3)
    assert traj.gripper_names == ("left", "right") and np.isfinite(traj.gripper).all()
    back = load_trajectory(save_trajectory(traj, tmp_path / "hands.npz"))
    np.testing.assert_array_equal(back.keypoints, traj.keypoints)
    np.testing.assert_array_equal(back.gripper, traj.gripper)
    # a hand-written file: keypoints and fps only
    np.savez(tmp_path / "min.npz", keypoints=traj.keypoints, fps=30.0)
    minimal = load_trajectory(tmp_path / "min.npz")
    assert minimal.q.shape == (4, 0) and minimal.gripper.shape == (4, 0)
    checked = Mano().check_trajectory(minimal)  # gripper columns filled from the keypoints
    np.testing.assert_allclose(checked.gripper, traj.gripper)


def test_keypoints_field_validation(tmp_path, mano):
    kp = two_hands(2).reshape(2, 42, 3)
    with pytest.raises(TrajectoryError, match=r"field 'keypoints': expected shape \(2, P, 3\)"):
        Trajectory((), np.zeros((2, 0)), 10, keypoints=kp[:1])
    bad = kp.copy()
    bad[1, 5, 0] = np.inf
    with pytest.raises(TrajectoryError, match="keypoints.*NaN marks a missing point.*frame 1, point 5"):
        Trajectory((), np.zeros((2, 0)), 10, keypoints=bad)
    np.savez(tmp_path / "str.npz", keypoints=np.array(["a", "b"]), fps=1.0)
    with pytest.raises(TrajectoryError, match="str.npz: field 'keypoints'"):
        load_trajectory(tmp_path / "str.npz")
    with pytest.raises(TrajectoryError, match=r"keypoints.*shape \(T, 42, 3\)"):
        mano.check_trajectory(Trajectory((), np.zeros((2, 0)), 10, keypoints=kp[:, :21]))
    with pytest.raises(TrajectoryError, match="keypoints.*missing"):
        mano.check_trajectory(Trajectory((), np.zeros((2, 0)), 10, gripper=np.ones((2, 2))))


def test_robot_embodiments_refuse_keypoints():
    sys.path.insert(0, str(REPO / "examples" / "oscar-toyarm"))
    from oscar_toyarm import ToyArm

    traj = Trajectory(
        ("base_yaw", "shoulder", "elbow", "wrist_pitch"),
        np.zeros((2, 4)),
        10,
        gripper=np.full((2, 1), 0.04),
        keypoints=np.zeros((2, 8, 3)),
    )
    with pytest.raises(TrajectoryError, match="keypoints.*computes its points from joint positions"):
        ToyArm().check_trajectory(traj)


def test_single_hand_input_and_errors():
    one = two_hands(2)[:, 1]
    traj = trajectory_from_keypoints(one, 30.0, hand="right")
    assert np.isnan(traj.keypoints[:, :21]).all() and np.isfinite(traj.keypoints[:, 21:]).all()
    assert traj.gripper[0, 0] == 1.0  # an absent hand holds "open"
    with pytest.raises(ValueError, match="hand='left' or hand='right'"):
        trajectory_from_keypoints(one, 30.0)
    with pytest.raises(ValueError, match=r"\(T, 2, 21, 3\)"):
        trajectory_from_keypoints(np.zeros((2, 3, 21, 3)), 30.0)


# ---- cameras ----------------------------------------------------------------------------


def test_world_keypoints_with_moving_camera_match_a_static_world_camera(mano):
    """Per-frame camera poses folded into the keypoints render exactly like the same
    world points seen through a camera file with that extrinsic."""
    T = 3
    hands = place(two_hands(1)[0].reshape(42, 3), rotation([1, 0, 0], 1.2), [0, 0, 0])
    target = np.array([0.3, 0.1, 0.8])
    world = np.array([hands - hands.mean(0) + target] * T)
    poses = np.stack([look_at([0.05 * t, -0.3 - 0.05 * t, 1.2], target) for t in range(T)])
    intr = Intrinsics(200.0, 200.0, 127.5, 71.5, 256, 144)
    converted = trajectory_from_keypoints(world.reshape(T, 2, 21, 3), 30.0, camera_poses=poses)
    ego = render_skeleton_video(mano, converted, egocentric_camera(200.0, 200.0, 127.5, 71.5, 256, 144))
    assert ego.reshape(T, -1).max(1).min() > 0
    for t in range(T):
        static = render_skeleton_video(
            mano,
            converted.replace(
                q=converted.q[t : t + 1], gripper=converted.gripper[t : t + 1], keypoints=world[t : t + 1]
            ),
            Camera(intr, poses[t]),
        )
        np.testing.assert_array_equal(static[0], ego[t])


def test_camera_pose_conventions():
    p = np.array([[[0.1, 0.2, 1.5]]])
    pose_cv = np.eye(4)[None]
    np.testing.assert_allclose(to_camera_frame(p, pose_cv), p)
    # an OpenGL/ARKit camera (y up, looking along -z) at the origin sees world (0.1, 0.2, -1.5) at cv (0.1, -0.2, 1.5)
    np.testing.assert_allclose(to_camera_frame(np.array([[[0.1, 0.2, -1.5]]]), pose_cv, "opengl"), [[[0.1, -0.2, 1.5]]])
    with pytest.raises(ValueError, match="rigid transforms"):
        to_camera_frame(p, 2 * pose_cv)
    with pytest.raises(ValueError, match=r"shape \(1, 4, 4\)"):
        to_camera_frame(p, np.eye(4))


def test_mounted_camera_is_refused(mano, example):
    traj, cam = example
    mounted = Camera(cam.intrinsics, np.eye(4), mount_link="head")
    with pytest.raises(Exception, match="mount"):
        render_skeleton_video(mano, traj.time_slice(0, 1), mounted)


# ---- rendering, missing hands -------------------------------------------------------------


def test_missing_hand_draws_nothing_of_it(mano):
    cam = egocentric_camera(200.0, 200.0, 127.5, 71.5, *SIZE)
    kp = two_hands(2)
    both = render_skeleton_video(mano, trajectory_from_keypoints(kp, 30.0), cam)
    assert both[:, :, :128].max() > 0 and both[:, :, 128:].max() > 0  # left hand on the left, right on the right
    kp[1, 1] = np.nan  # frame 1: no right hand
    kp[0, 1, 8] = np.nan  # frame 0: the right index tip is lost
    video = render_skeleton_video(mano, trajectory_from_keypoints(kp, 30.0), cam)
    assert video[1, :, 128:].max() == 0  # no points, bones or indicator of the right hand
    np.testing.assert_array_equal(video[1, :, :128], both[1, :, :128])
    changed = np.any(video[0] != both[0], axis=-1)
    assert changed.any() and changed.sum() < 0.2 * np.any(both[0] > 0, axis=-1).sum()  # only near that tip


def test_render_example_every_frame_shows_both_hands(mano, example):
    traj, cam = example
    assert len(traj) >= 81
    assert np.isfinite(traj.keypoints).all()
    video = render_skeleton_video(mano, traj, cam, SIZE)
    w = SIZE[0] // 2
    assert (video[:, :, :w].reshape(len(traj), -1).max(1) > 0).all()
    assert (video[:, :, w:].reshape(len(traj), -1).max(1) > 0).all()


def test_indicator_follows_openness_on_a_single_frame(mano, example):
    """The conformance check of the indicator, with the keypoints sliced along with q."""
    traj, cam = example
    cam = cam.resized(*SIZE)
    one = traj.time_slice(0, 1)
    renders = [render_skeleton_video(mano, one.replace(gripper=np.full((1, 2), o)), cam)[0] for o in (0.2, 0.8)]
    marks = project_skeleton(mano, one, cam).grippers
    for k in range(2):
        u, v = marks.uv[0, k]
        assert marks.visible[0, k] and 0 <= u < SIZE[0] and 0 <= v < SIZE[1]
        ys, xs = np.mgrid[: SIZE[1], : SIZE[0]]
        near = (xs - u) ** 2 + (ys - v) ** 2 <= 12**2
        assert np.any(renders[0][near] != renders[1][near])


# ---- flexion --------------------------------------------------------------------------------


def test_openness_is_monotone_from_open_hand_to_fist():
    curls = np.linspace(0.0, 1.0, 41)
    kp = np.stack([hand_keypoints(c) for c in curls])
    o = hand_openness(kp)
    assert o[0] == pytest.approx(1.0) and o[-1] == 0.0
    assert np.all(np.diff(o) <= 0)  # never opens while the hand closes
    assert np.all(np.diff(o[o > 0]) < 0)  # strictly until it reads "closed"
    assert (o > 0).sum() >= 35  # and it reads "closed" only near the fist
    # the left hand (a mirror image) gives the same signal
    np.testing.assert_allclose(hand_openness(np.stack([hand_keypoints(c, side="left") for c in curls])), o)


def test_openness_ignores_pose_position_and_scale():
    kp = hand_keypoints(0.5)
    moved = place(kp, rotation([0.3, -1, 0.5], 2.0), [1.0, -2.0, 0.5]) * 7.0
    assert hand_openness(moved) == pytest.approx(hand_openness(kp))
    assert 0.4 < hand_openness(kp) < 0.8


def test_openness_with_missing_points():
    kp = hand_keypoints(0.3)
    partial = kp.copy()
    partial[8] = np.nan  # index tip lost: the other three fingers still give a value
    assert np.isfinite(hand_openness(partial))
    assert np.isnan(hand_openness(np.full((21, 3), np.nan)))
    assert R_FIST < 1.0
    held = hold_missing(np.array([[np.nan, np.nan], [0.4, np.nan], [np.nan, np.nan], [0.2, np.nan]]))
    np.testing.assert_array_equal(held, [[0.4, 1.0], [0.4, 1.0], [0.4, 1.0], [0.2, 1.0]])


# ---- the MANO-parameter path without smplx ---------------------------------------------------


def test_mano_parameters_without_smplx_raise_the_install_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "smplx", None)
    params = {"right": {"global_orient": np.zeros((2, 3)), "hand_pose": np.zeros((2, 45))}}
    with pytest.raises(ImportError) as err:
        trajectory_from_mano(params, fps=30.0, model_dir="/nonexistent")
    assert str(err.value) == SMPLX_MISSING
    assert 'pip install "oscar-wm[mano]"' in SMPLX_MISSING
    # the keypoint path does not need it
    assert len(trajectory_from_keypoints(two_hands(2), 30.0)) == 2
