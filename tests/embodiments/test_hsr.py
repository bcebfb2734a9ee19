"""The hsr plugin: the xacro, FK against the reference URDF, base pose, hand, head camera, the AIROA-MoMa adapter.

FK oracle: Toyota's ``hsrb4s.urdf`` (hsrb_description, Clear BSD) in the
shared reference folder, evaluated with yourdfpy (an independent parser and
FK, which also resolves the reference's mimic joints); skipped when that
folder is absent. The plugin's xacro keeps the reference's link and joint
names, so links correspond one to one.

The adapter is checked on small synthetic records built with the LeRobot
layout documented for AIROA-MoMa (see embodiments/hsr/README.md).
"""

import math

import numpy as np
import pytest
from _paths import SHARED
from render.golden_cases.hsr import CONFIGS as GOLDEN_CONFIGS, SUITE as GOLDEN

from oscar_core import (
    Camera,
    CameraFileError,
    Intrinsics,
    Trajectory,
    TrajectoryError,
    get_embodiment,
    load_camera,
    load_trajectory,
    render_skeleton_video,
)
from oscar_core.testing import compare_images
from oscar_embodiments import hsr as plugin
from oscar_embodiments.hsr import HAND_RANGE, HEAD_CAMERA_LINK, HSR, JOINTS, base_pose_from_xy_yaw
from oscar_embodiments.hsr.adapters import AIROA_MOMA_FPS, AIROA_MOMA_STATE_NAMES, HEAD_INTRINSICS, from_airoa_moma

REFERENCE = SHARED / "reference" / "hsr" / "hsrb4s.urdf"
REACH = [0.12, -1.50, 0.0, -0.05, 0.0, 0.05, -0.70]


@pytest.fixture(scope="module")
def hsr():
    return HSR()


def reach(T=1, hand=1.0, base_pose=None):
    return Trajectory(JOINTS, np.tile(REACH, (T, 1)), fps=10, gripper=np.full((T, 1), hand), base_pose=base_pose)


# --------------------------------------------------------------------------- FK against the reference


@pytest.fixture(scope="module")
def reference():
    yourdfpy = pytest.importorskip("yourdfpy")
    if not REFERENCE.is_file():
        pytest.skip(f"reference URDF not available at {REFERENCE}")
    return yourdfpy.URDF.load(
        str(REFERENCE), load_meshes=False, build_collision_scene_graph=False, load_collision_meshes=False
    )


def test_fk_matches_the_reference_on_random_configurations(hsr, reference):
    ours = hsr.tree
    assert set(ours.links) <= set(reference.link_map), "every link of the xacro exists in the reference"
    assert all(n in reference.joint_map for n in ours.joint_names)  # 7 joints + hand_motor_joint
    lo, hi = ours.limits()
    rng = np.random.default_rng(3)
    q = rng.uniform(lo, hi, size=(12, len(lo)))
    poses = hsr.fk(q, links=list(ours.links)).numpy()
    worst_p = worst_r = 0.0
    for t in range(len(q)):
        reference.update_cfg({n: float(v) for n, v in zip(ours.joint_names, q[t])})  # wheels, springs, ... at 0
        for k, link in enumerate(ours.links):
            T = reference.get_transform(link, reference.base_link)
            worst_p = max(worst_p, np.abs(T[:3, 3] - poses[t, k, :3, 3]).max())
            worst_r = max(worst_r, np.abs(T[:3, :3] - poses[t, k, :3, :3]).max())
    assert worst_p < 1e-6 and worst_r < 1e-6, (worst_p, worst_r)


def test_torso_mimics_half_the_arm_lift(hsr):
    q = np.zeros((3, len(hsr.tree.joint_names)))
    q[:, 0] = [0.0, 0.3, 0.69]  # arm_lift_joint
    z = hsr.fk(q, links=["torso_lift_link", "arm_lift_link"]).numpy()[:, :, 2, 3]
    assert np.allclose(z[:, 0], 0.752 + 0.5 * q[:, 0]) and np.allclose(z[:, 1], 0.340 + q[:, 0])


def test_limits_match_the_reference(hsr, reference):
    for joint in hsr.tree.joints:
        ref = reference.joint_map[joint.name]
        assert (joint.parent, joint.child) == (ref.parent, ref.child)
        if joint.movable:
            assert joint.type == ref.type and np.allclose(joint.axis, ref.axis)
            assert (joint.lower, joint.upper) == pytest.approx((ref.limit.lower, ref.limit.upper))


# --------------------------------------------------------------------------- the plugin itself


def test_registered_through_the_entry_point_with_a_xacro(hsr):
    assert plugin.oscar_register_embodiments() == [HSR]
    emb = get_embodiment("hsr")
    assert isinstance(emb, HSR) and emb.problems() == []
    assert emb.urdf is None and str(emb.xacro).endswith("hsrb.urdf.xacro")
    assert emb.license == "BSD-3-Clause-Clear"
    assert hsr.joint_names == JOINTS
    assert [j.name for j in hsr.tree.joints if j.mimic] == [
        "torso_lift_joint",
        "hand_l_proximal_joint",
        "hand_l_distal_joint",
        "hand_r_proximal_joint",
        "hand_r_distal_joint",
    ]


def test_base_pose_from_xy_yaw():
    T = base_pose_from_xy_yaw([0.0, 1.0], [0.0, 2.0], [0.0, math.pi / 2])
    assert T.shape == (2, 4, 4) and np.allclose(T[0], np.eye(4))
    assert np.allclose(T[1], [[0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 0], [0, 0, 0, 1]])
    assert base_pose_from_xy_yaw(0.5, 0.0, np.zeros(3)).shape == (3, 4, 4)  # scalars broadcast
    with pytest.raises(ValueError, match=r"shape \(T,\)"):
        base_pose_from_xy_yaw(np.zeros((2, 2)), 0.0, 0.0)
    with pytest.raises(ValueError, match="finite"):
        base_pose_from_xy_yaw([np.nan], [0.0], [0.0])


def test_base_pose_moves_the_whole_robot(hsr):
    pose = base_pose_from_xy_yaw(0.4, -0.2, 0.7)
    at_origin = hsr.frames(hsr.check_trajectory(reach()), mount_link=HEAD_CAMERA_LINK)
    moved = hsr.frames(hsr.check_trajectory(reach(base_pose=pose)), mount_link=HEAD_CAMERA_LINK)
    R, t = pose[0, :3, :3], pose[0, :3, 3]
    assert np.allclose(moved.points[0], at_origin.points[0] @ R.T + t)
    assert np.allclose(moved.mount_pose[0], pose[0] @ at_origin.mount_pose[0])


def test_base_pose_moves_the_external_view_but_not_the_head_view():
    """Rendered as the golden images are (tests/render/golden_cases/hsr.py): the head camera rides on the robot."""
    q, hand, _ = GOLDEN_CONFIGS["reach_half_open"]
    views = {}
    for name, pose in (("origin", (0.0, 0.0, 0.0)), ("moved", (0.3, -0.2, 0.4))):
        views[name] = [GOLDEN.render(((q, hand, pose), camera)) for camera in ("head", "external")]
    assert compare_images(views["origin"][0], views["moved"][0]) == 0.0
    assert compare_images(views["origin"][1], views["moved"][1]) > GOLDEN.tol


def test_golden_configs_are_within_limits_and_one_is_near_a_limit(hsr):
    """The configurations of the golden images (tests/render/golden_cases/hsr.py)."""
    lo, hi = hsr.tree.limits()
    keep = [hsr.tree.joint_names.index(n) for n in JOINTS]
    lo, hi = lo[keep], hi[keep]
    for q, hand, _ in GOLDEN_CONFIGS.values():
        assert np.all((np.array(q) >= lo) & (np.array(q) <= hi))
        assert HAND_RANGE[0] <= hand <= HAND_RANGE[1]
    q = np.array(GOLDEN_CONFIGS["limits_open"][0])
    assert np.min(np.minimum(q - lo, hi - q)) <= 0.02


def test_hand_signal(hsr):
    tips = [hsr.skeleton.links.index(n) for n in ("hand_l_finger_tip_frame", "hand_r_finger_tip_frame")]
    gap, openness = {}, {}
    for hand in (-0.5, 0.0, 0.62, HAND_RANGE[1]):
        frames = hsr.frames(hsr.check_trajectory(reach(hand=hand)))
        gap[hand] = np.linalg.norm(frames.points[0, tips[0]] - frames.points[0, tips[1]])
        openness[hand] = frames.openness[0, 0]
    assert openness == pytest.approx({-0.5: 0.0, 0.0: 0.0, 0.62: 0.5, 1.24: 1.0})
    assert gap[-0.5] == pytest.approx(gap[0.0])  # squeezing past contact does not cross the fingers
    assert gap[0.0] < 0.01 < gap[0.62] < gap[1.24]


def test_example_assets(hsr):
    traj = hsr.check_trajectory(load_trajectory(hsr.example_trajectory))
    assert len(traj) >= 81 and traj.base_pose is not None
    assert np.linalg.norm(traj.base_pose[-1, :2, 3] - traj.base_pose[0, :2, 3]) > 0.1  # the base drives
    hand = traj.gripper[:, 0]
    assert hand.max() > 1.0 and hand.min() < 0.0 and hand[-1] > 0.9  # opens, closes on the object, opens again
    cam = load_camera(hsr.example_camera)
    assert cam.mount_link == HEAD_CAMERA_LINK and np.array_equal(cam.extrinsic, np.eye(4))
    video = render_skeleton_video(hsr, traj, cam, (160, 120))
    assert (video.reshape(len(traj), -1).max(axis=1) > 0).all()


def test_head_camera_looks_along_the_head(hsr):
    """head_rgbd_sensor_link is an optical frame: its z axis is the head's forward (x) axis."""
    for tilt in (-1.0, 0.0, 0.4):
        q = np.array([REACH])
        q[0, JOINTS.index("head_tilt_joint")] = tilt
        frames = hsr.frames(
            hsr.check_trajectory(Trajectory(JOINTS, q, 10, gripper=[[1.0]])), mount_link=HEAD_CAMERA_LINK
        )
        tilt_link = hsr.fk(
            hsr.full_configuration(Trajectory(JOINTS, q, 10, gripper=[[1.0]])), links=["head_tilt_link"]
        ).numpy()[0, 0]
        assert np.allclose(frames.mount_pose[0, :3, 2], tilt_link[:3, 0])
        assert frames.mount_pose[0, 2, 2] == pytest.approx(math.sin(tilt), abs=1e-9)  # + tilt looks up


# --------------------------------------------------------------------------- the AIROA-MoMa adapter


def lerobot_rows(T=6, seed=0):
    rng = np.random.default_rng(seed)
    q = np.array(REACH) + rng.normal(0, 0.02, (T, 7))
    hand = np.linspace(1.0, -0.2, T)
    state8 = np.concatenate([q[:, :5], hand[:, None], q[:, 5:]], axis=1)  # hand_motor_joint sits before the head
    return q, hand, state8


def test_airoa_moma_8_wide_layout(hsr):
    q, hand, state = lerobot_rows()
    record = {
        "observation.state": [row.astype(np.float32).tolist() for row in state],  # parquet list cells
        "timestamp": np.arange(len(q)) * 0.1,
    }
    traj, cam = from_airoa_moma(record, source="episode_000012")
    assert traj.joint_names == JOINTS and traj.gripper_names == ("hand",)
    assert np.allclose(traj.q, q, atol=1e-6) and np.allclose(traj.gripper[:, 0], hand, atol=1e-6)
    assert traj.fps == pytest.approx(10.0) and traj.base_pose is None and traj.source == "episode_000012"
    assert cam.mount_link == HEAD_CAMERA_LINK and cam.embodiment == "hsr" and np.array_equal(cam.extrinsic, np.eye(4))
    assert cam.intrinsics == HEAD_INTRINSICS and HEAD_INTRINSICS.fx == pytest.approx(554.38, abs=0.01)
    video = render_skeleton_video(hsr, traj, cam, (160, 120))
    assert video.shape == (len(q), 120, 160, 3) and video.max() > 0


def test_airoa_moma_padded_layout_named_by_info_json(hsr):
    q, hand, state8 = lerobot_rows()
    names = (
        list(AIROA_MOMA_STATE_NAMES[:5])
        + ["zero_5", "hand_motor_joint"]
        + [f"zero_{k}" for k in range(7, 11)]
        + ["head_pan_joint", "head_tilt_joint"]
        + [f"zero_{k}" for k in range(13, 32)]
    )
    state = np.zeros((len(q), 32))
    for j, name in enumerate(AIROA_MOMA_STATE_NAMES):
        state[:, names.index(name)] = state8[:, j]
    info = {
        "fps": 10,
        "robot_type": "hsr",
        "features": {"observation.state": {"dtype": "float32", "shape": [32], "names": names}},
    }
    xy_yaw = np.stack([np.linspace(0, 0.3, len(q)), np.zeros(len(q)), np.linspace(0, 0.2, len(q))], axis=1)
    traj, _ = from_airoa_moma({"observation.state": state, "info": info, "base_pose": xy_yaw})
    assert np.allclose(traj.q, q) and np.allclose(traj.gripper[:, 0], hand)
    assert traj.fps == 10.0 and traj.base_pose.shape == (len(q), 4, 4)
    assert np.allclose(traj.base_pose[-1], base_pose_from_xy_yaw(0.3, 0.0, 0.2)[0])
    # names may also come directly, in LeRobot's {"motors": [...]} form
    traj2, _ = from_airoa_moma({"observation.state": state, "names": {"observation.state": {"motors": names}}})
    assert np.allclose(traj2.q, q) and traj2.fps == AIROA_MOMA_FPS


def test_airoa_moma_camera_info(hsr):
    _, _, state = lerobot_rows(T=2)
    info = {
        "width": 640,
        "height": 480,
        "K": [537.0, 0.0, 320.5, 0.0, 536.5, 243.1, 0.0, 0.0, 1.0],
        "D": [0.02, -0.05, 0.0, 0.001, 0.0],
    }
    _, cam = from_airoa_moma({"observation.state": state, "camera_info": info})
    i = cam.intrinsics
    assert (i.fx, i.fy, i.cx, i.cy, i.width, i.height) == (537.0, 536.5, 320.5, 243.1, 640, 480)
    assert i.distortion == (0.02, -0.05, 0.0, 0.001, 0.0)
    with pytest.raises(CameraFileError, match="9 numbers") as err:
        from_airoa_moma({"observation.state": state}, camera_info={**info, "K": [1.0, 2.0]}, source="ep7")
    assert err.value.field == "camera_info.K" and err.value.path == "ep7"


@pytest.mark.parametrize(
    "record, field, words",
    [
        ({}, "observation.state", "missing"),
        ({"observation.state": np.zeros((4, 9))}, "names", "8-wide layout"),
        ({"observation.state": np.zeros((4, 3)), "names": ["a", "b", "c"]}, "observation.state names", "missing"),
        ({"observation.state": np.zeros((4, 8)), "names": list(AIROA_MOMA_STATE_NAMES)[:7]}, "names", "8 names"),
        ({"observation.state": np.full((4, 8), np.nan)}, "observation.state", "non-finite"),
        ({"observation.state": np.zeros((4, 8)), "base_pose": np.zeros((4, 2))}, "base_pose", "shape (4, 3)"),
        ({"observation.state": np.zeros((4, 8)), "timestamp": np.zeros(3)}, "timestamp", "4 timestamps"),
    ],
)
def test_airoa_moma_bad_input(record, field, words):
    with pytest.raises(TrajectoryError, match="ep3") as err:
        from_airoa_moma(record, source="ep3")
    assert err.value.field == field and words in str(err.value)


# --------------------------------------------------------------------------- bad input to the embodiment


def test_wrong_joint_count_or_names_are_refused(hsr):
    with pytest.raises(TrajectoryError, match="the 7 joints of 'hsr'") as err:
        hsr.check_trajectory(Trajectory(JOINTS + ("torso_lift_joint",), np.zeros((1, 8)), 10, gripper=[[1.0]]))
    assert "unknown ['torso_lift_joint']" in str(err.value)  # the torso is a mimic joint, never given
    with pytest.raises(TrajectoryError, match=r"missing \['head_tilt_joint'\]"):
        hsr.check_trajectory(Trajectory(JOINTS[:-1], np.zeros((1, 6)), 10, gripper=[[1.0]]))


def test_hand_outside_its_range_is_refused(hsr):
    traj = hsr.check_trajectory(reach(hand=2.0))
    with pytest.raises(TrajectoryError, match=r"gripper\[hand\].*values in \[-0.798, 1.24\].*found 2"):
        hsr.frames(traj)


def test_camera_for_another_mount_or_embodiment_is_refused(hsr):
    intr = Intrinsics(554.0, 554.0, 319.5, 239.5, 640, 480)
    hsr.check_camera(Camera(intr, np.eye(4)))  # a static outside camera fits any embodiment
    with pytest.raises(CameraFileError, match="mount link 'head_rgbd_sensor_link' for embodiment 'hsr'") as err:
        render_skeleton_video(
            hsr, reach(), Camera(intr, np.eye(4), mount_link="head_tilt_link"), camera_source="tilt.json"
        )
    assert err.value.path == "tilt.json" and err.value.found == "mount link 'head_tilt_link'"
    with pytest.raises(CameraFileError, match="expected 'hsr', found 'agibot_g1'"):
        hsr.check_camera(Camera(intr, np.eye(4), mount_link=HEAD_CAMERA_LINK, embodiment="agibot_g1"))
