"""The franka plugin: URDF lookup, skeleton, dataset adapters, bad input.

FK against yourdfpy on the same URDF is covered in test_kinematics.py; here
the adapters are checked on small synthetic records built with each dataset's
documented layout (see embodiments/franka/README.md for the sources).
"""

import importlib.metadata

import numpy as np
import pytest
from render.golden_cases.franka import CONFIGS as GOLDEN_CONFIGS

from oscar_core import (
    Camera,
    CameraFileError,
    Intrinsics,
    PluginError,
    Trajectory,
    TrajectoryError,
    project,
    render_skeleton_video,
)
from oscar_embodiments import franka as franka_plugin
from oscar_embodiments.franka import JOINT_NAMES, Franka, panda_urdf_path
from oscar_embodiments.franka.adapters import from_droid, from_interndata, from_rh20t, rh20t_base_to_camera

Rotation = pytest.importorskip("scipy.spatial.transform").Rotation

READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]


@pytest.fixture(scope="module")
def franka():
    return Franka()


def rigid(rng) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = rng.uniform(-1, 1, 3)
    return T


def ready_traj(T=3, width=0.08):
    return Trajectory(JOINT_NAMES, np.tile(READY, (T, 1)), fps=10, gripper=np.full((T, 1), width))


# --------------------------------------------------------------------------- the plugin itself


def test_hook_returns_the_class():
    from oscar_embodiments.franka.robotiq import FrankaRobotiq

    assert franka_plugin.oscar_register_embodiments() == [Franka, FrankaRobotiq]


def test_registered_through_the_entry_point():
    eps = {ep.name for ep in importlib.metadata.entry_points(group="oscar")}
    if "franka" not in eps:
        pytest.skip("oscar is not installed (pip install -e .): no entry points to check")
    from oscar_core import get_embodiment

    assert isinstance(get_embodiment("franka"), Franka)


def test_urdf_is_found_lazily_in_the_example_robot_data_wheel(franka):
    assert not isinstance(Franka.urdf, (str, type(panda_urdf_path())))  # class access: the lazy descriptor
    path = franka.urdf
    assert path.is_file() and path.as_posix().endswith("panda_description/urdf/panda.urdf")
    assert "example-robot-data" in repr(Franka.urdf)


def test_missing_distribution_is_named(monkeypatch):
    def missing(name):
        raise importlib.metadata.PackageNotFoundError(name)

    panda_urdf_path.cache_clear()
    monkeypatch.setattr(importlib.metadata, "distribution", missing)
    try:
        with pytest.raises(PluginError, match=r"example-robot-data.*pip install example-robot-data"):
            panda_urdf_path()
    finally:
        monkeypatch.undo()
        panda_urdf_path.cache_clear()
    assert panda_urdf_path().is_file()


def test_joint_order_excludes_the_fingers(franka):
    assert franka.joint_names == JOINT_NAMES
    assert "panda_finger_joint1" in franka.tree.joint_names


@pytest.mark.parametrize("width", [0.0, 0.03, 0.08])
def test_fingertips_are_as_far_apart_as_the_gripper_width(franka, width):
    frames = franka.frames(franka.check_trajectory(ready_traj(1, width)))
    k = {l: i for i, l in enumerate(franka.skeleton.links)}
    tips = frames.points[0, [k["panda_leftfinger"], k["panda_rightfinger"]]]
    assert np.linalg.norm(tips[0] - tips[1]) == pytest.approx(width, abs=1e-9)
    # the tips sit at the TCP height, 0.1034 m beyond the flange along the hand axis
    hand = franka.fk(franka.full_configuration(ready_traj(1, width)), links=["panda_hand"]).numpy()[0, 0]
    assert hand[:3, :3].T @ (tips.mean(0) - hand[:3, 3]) == pytest.approx([0, 0, 0.1034], abs=1e-9)
    assert frames.openness[0, 0] == pytest.approx(width / 0.08)


def test_skeleton_leaves_out_only_coincident_links(franka):
    q = np.random.default_rng(0).uniform(*franka.tree.limits(), size=(5, len(franka.tree.joint_names)))
    poses = franka.fk(q, links=["panda_link1", "panda_link2", "panda_link5", "panda_link6"]).numpy()
    assert np.abs(poses[:, 0, :3, 3] - poses[:, 1, :3, 3]).max() < 1e-12  # link2 sits on link1
    assert np.abs(poses[:, 2, :3, 3] - poses[:, 3, :3, 3]).max() < 1e-12  # link6 sits on link5
    assert len(franka.edges) == len(franka.skeleton.links) - 1


def test_golden_near_limits_config_is_within_limits(franka):
    """The near-limits configuration of the golden images (tests/render/golden_cases/franka.py) is inside the
    limits, less than 0.1 rad from one of them."""
    lo, hi = franka.tree.limits()
    q = np.array(GOLDEN_CONFIGS["near_limits_closed"][0])
    assert np.all(q > lo[:7]) and np.all(q < hi[:7])
    assert np.min(np.minimum(q - lo[:7], hi[:7] - q)) < 0.1


# --------------------------------------------------------------------------- DROID


def droid_record(T=4, serial="24259877_left", rng=None):
    rng = rng or np.random.default_rng(1)
    lo, hi = Franka().tree.limits()
    q = rng.uniform(lo[:7] + 0.1, hi[:7] - 0.1, size=(T, 7))
    pos = np.linspace(0.0, 1.0, T)
    ext = np.array([0.9, -0.6, 0.7, -2.2, 0.1, 0.9])  # [x, y, z, roll, pitch, yaw]
    K = np.array([[522.0, 0.0, 640.5], [0.0, 521.0, 355.0], [0.0, 0.0, 1.0]])
    record = {
        "observation": {
            "robot_state": {"joint_positions": q, "gripper_position": pos},
            "camera_extrinsics": {serial: np.tile(ext, (T, 1))},
            "camera_intrinsics": {serial: np.tile(K, (T, 1, 1))},
        }
    }
    return record, q, pos, ext, K


def test_droid_raw_layout():
    record, q, pos, ext, K = droid_record()
    traj, cam = from_droid(record, "24259877_left")
    assert traj.joint_names == JOINT_NAMES and np.allclose(traj.q, q) and traj.fps == 15.0
    # the Robotiq 2F-85 DROID mounts (franka_robotiq): its position as stored, 0 open .. 1 closed
    assert np.array_equal(traj.gripper[:, 0], pos)
    assert cam.direction == "camera_to_world" and cam.convention == "opencv" and cam.embodiment == "franka_robotiq"
    # the Franka Hand instead (the behaviour before franka_robotiq): Robotiq position 1 = closed -> width 0
    hand_traj, hand_cam = from_droid(record, "24259877_left", embodiment="franka")
    assert np.allclose(hand_traj.gripper[:, 0], 0.08 * (1 - pos)) and hand_cam.embodiment == "franka"
    assert np.array_equal(hand_cam.extrinsic, cam.extrinsic) and np.array_equal(hand_traj.q, traj.q)
    with pytest.raises(ValueError, match="embodiment must be one of"):
        from_droid(record, "24259877_left", embodiment="kuka")
    # DROID's euler convention is scipy's "xyz" (droid/misc/transformations.py)
    assert np.allclose(cam.extrinsic[:3, :3], Rotation.from_euler("xyz", ext[3:]).as_matrix(), atol=1e-12)
    assert np.allclose(cam.extrinsic[:3, 3], ext[:3])
    i = cam.intrinsics
    assert (i.fx, i.fy, i.cx, i.cy, i.width, i.height) == (522.0, 521.0, 640.5, 355.0, 1280, 720)


def test_droid_camera_projects_like_opencv():
    cv2 = pytest.importorskip("cv2")
    record, *_ = droid_record()
    _, cam = from_droid(record, "24259877_left")
    pts = np.array([[0.3, 0.1, 0.2], [0.5, -0.2, 0.05], [0.1, 0.0, 0.6]])
    T_cam_base = np.linalg.inv(cam.extrinsic)
    rvec, _ = cv2.Rodrigues(T_cam_base[:3, :3])
    expected, _ = cv2.projectPoints(pts, rvec, T_cam_base[:3, 3], cam.intrinsics.matrix(), None)
    assert np.allclose(project(pts, cam).uv, expected[:, 0], atol=1e-8)


def test_droid_rlds_layout_with_explicit_calibration(franka):
    record, q, pos, ext, K = droid_record()
    rlds = {"observation/joint_position": q, "observation/gripper_position": pos[:, None]}
    traj, cam = from_droid(
        rlds, "24259877_left", extrinsic=ext, intrinsics=(522.0, 521.0, 640.5, 355.0), embodiment="franka"
    )
    ref_traj, ref_cam = from_droid(record, "24259877_left", embodiment="franka")
    assert np.allclose(traj.q, ref_traj.q) and np.allclose(traj.gripper, ref_traj.gripper)
    assert cam == ref_cam
    video = render_skeleton_video(franka, traj, cam, (128, 72))
    assert video.shape == (4, 72, 128, 3)


def test_droid_bad_input():
    record, *_ = droid_record()
    record["observation"]["robot_state"]["gripper_position"] = np.array([0.0, 0.5, 1.3, 1.0])
    with pytest.raises(TrajectoryError, match=r"gripper_position.*0 = open, 1 = closed.*1\.3 at frame 2"):
        from_droid(record, "24259877_left")

    record, *_ = droid_record()
    moving = record["observation"]["camera_extrinsics"]["24259877_left"]
    moving[2:, 0] += 0.05  # a wrist camera's pose changes every frame
    with pytest.raises(CameraFileError, match=r"static camera.*wrist camera"):
        from_droid(record, "24259877_left")

    record, *_ = droid_record()
    with pytest.raises(CameraFileError, match=r"camera_extrinsics/1234_left.*missing"):
        from_droid(record, "1234_left")

    record, *_ = droid_record()
    record["observation"]["robot_state"]["joint_positions"] = record["observation"]["robot_state"]["joint_positions"][
        :, :6
    ]
    with pytest.raises(TrajectoryError, match=r"joint_positions.*shape \(T, 7\).*found shape \(4, 6\)"):
        from_droid(record, "24259877_left")

    record, *_ = droid_record()
    record["observation"]["robot_state"]["joint_positions"] = np.degrees(
        record["observation"]["robot_state"]["joint_positions"]
    )
    with pytest.raises(TrajectoryError, match=r"radians.*degrees\?"):
        from_droid(record, "24259877_left")


# --------------------------------------------------------------------------- RH20T cfg5


SERIAL, IN_HAND = "036422060215", "104422070042"


def rh20t_record(T=6):
    rng = np.random.default_rng(2)
    ts = 1631270000000 + 100 * np.arange(T)  # 10 fps, milliseconds
    lo, hi = Franka().tree.limits()
    q = rng.uniform(lo[:7] + 0.1, hi[:7] - 0.1, size=(T, 7))
    joint = {
        SERIAL: {int(t): np.concatenate([q[i], rng.normal(size=7)]) for i, t in enumerate(ts)}
    }  # angles + velocities
    gts = ts[::2] + 30  # gripper sampled at other times
    widths = np.linspace(80.0, 10.0, len(gts))
    gripper = {
        SERIAL: {int(t): {"gripper_info": [w, 0.0, 0.0], "gripper_command": [w, 0.0, 0.0]} for t, w in zip(gts, widths)}
    }
    K = np.array([[910.0, 0.0, 640.0, 0.0], [0.0, 909.0, 362.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    E = np.linalg.inv(rigid(rng))
    return joint, gripper, {SERIAL: K}, {SERIAL: E[None]}, q, ts, gts, widths


def test_rh20t_cfg5_layout(franka):
    joint, gripper, intr, ext, q, ts, gts, widths = rh20t_record()
    traj, cam = from_rh20t(joint, gripper, intr, ext, SERIAL)
    assert traj.joint_names == JOINT_NAMES and np.allclose(traj.q, q)
    assert traj.fps == pytest.approx(10.0) and np.allclose(traj.timestamps, (ts - ts[0]) / 1000)
    assert np.allclose(traj.gripper[:, 0], np.interp(ts, gts, widths) / 1000)  # mm -> m at the joint times
    assert cam.direction == "world_to_camera" and cam.convention == "opencv"
    assert np.allclose(cam.extrinsic, ext[SERIAL][0])
    assert (cam.intrinsics.fx, cam.intrinsics.cy, cam.intrinsics.width) == (910.0, 362.0, 1280)
    # the base origin projects through K [R | t]
    t = ext[SERIAL][0][:3, 3]
    assert np.allclose(project(np.zeros(3), cam).uv, (intr[SERIAL][:, :3] @ t)[:2] / t[2])
    franka.check_trajectory(traj)


def test_rh20t_base_to_camera_recovers_the_base_aligned_extrinsic():
    rng = np.random.default_rng(3)
    T_cam_base, T_world_base, T_base_tcp, tc_mat = (rigid(rng) for _ in range(4))
    E = {
        SERIAL: (T_cam_base @ np.linalg.inv(T_world_base))[None],  # marker (world) -> camera
        IN_HAND: (tc_mat @ np.linalg.inv(T_base_tcp) @ np.linalg.inv(T_world_base))[None],
    }
    wxyz = Rotation.from_matrix(T_base_tcp[:3, :3]).as_quat(scalar_first=True)
    calib_tcp = np.concatenate([T_base_tcp[:3, 3], wxyz])
    got = rh20t_base_to_camera(E, SERIAL, IN_HAND, tc_mat, calib_tcp)
    assert np.allclose(got, T_cam_base, atol=1e-9)


def test_rh20t_bad_input():
    joint, gripper, intr, ext, *_ = rh20t_record()
    with pytest.raises(TrajectoryError, match=rf"joint\['999'\].*have \['{SERIAL}'\]"):
        from_rh20t(joint, gripper, intr, ext, "999")
    first = next(iter(gripper[SERIAL]))
    gripper[SERIAL][first]["gripper_info"] = [120.0, 0, 0]
    with pytest.raises(TrajectoryError, match=r"Franka Hand width in millimetres in \[0, 80\]"):
        from_rh20t(joint, gripper, intr, ext, SERIAL)
    joint, gripper, intr, ext, *_ = rh20t_record()
    joint[SERIAL] = {t: v[:6] for t, v in joint[SERIAL].items()}
    with pytest.raises(TrajectoryError, match=r"at least 7 values per frame"):
        from_rh20t(joint, gripper, intr, ext, SERIAL)
    joint, gripper, intr, ext, *_ = rh20t_record()
    ext[SERIAL] = np.diag([1.0, 1.0, 2.0, 1.0])
    with pytest.raises(CameraFileError, match=r"rigid transform"):
        from_rh20t(joint, gripper, intr, ext, SERIAL)


# --------------------------------------------------------------------------- InternData-A1


def interndata_frames(T=5, as_cells=False):
    rng = np.random.default_rng(4)
    lo, hi = Franka().tree.limits()
    q = rng.uniform(lo[:7] + 0.1, hi[:7] - 0.1, size=(T, 7)).astype(np.float32)
    width = np.linspace(0.08, 0.0, T, dtype=np.float32)[:, None]
    T_base_cam = rigid(rng)
    wxyz = Rotation.from_matrix(T_base_cam[:3, :3]).as_quat(scalar_first=True)
    pose = np.tile(np.concatenate([T_base_cam[:3, 3], wxyz]), (T, 1)).astype(np.float32)
    intr = np.tile([[615.0, 615.0, 320.0, 240.0]], (T, 1)).astype(np.float32)
    cols = {
        "states.joint.position": q,
        "states.gripper.position": width,
        "head_camera_intrinsics": intr,
        "head_camera_to_robot_extrinsics": pose,
        "timestamp": (np.arange(T) / 30).astype(np.float32),
    }
    if as_cells:  # what a pandas / pyarrow list column gives: one array per row
        cols = {k: list(v) for k, v in cols.items()}
    return cols, q, width, T_base_cam


@pytest.mark.parametrize("as_cells", [False, True])
def test_interndata_layout(franka, as_cells):
    cols, q, width, T_base_cam = interndata_frames(as_cells=as_cells)
    traj, cam = from_interndata(cols)
    assert traj.joint_names == JOINT_NAMES and np.allclose(traj.q, q)
    assert np.allclose(traj.gripper, width) and traj.fps == pytest.approx(30.0, rel=1e-5)
    assert cam.direction == "camera_to_world" and cam.convention == "opencv"
    assert np.allclose(cam.extrinsic, T_base_cam, atol=1e-6)  # float32 storage
    assert (cam.intrinsics.width, cam.intrinsics.height, cam.intrinsics.fx) == (640, 480, 615.0)
    franka.check_trajectory(traj)


def test_interndata_bad_input():
    cols, *_ = interndata_frames()
    with pytest.raises(CameraFileError, match=r"'head'.*hand camera moves"):
        from_interndata(cols, camera="hand")
    cols, *_ = interndata_frames()
    cols["head_camera_to_robot_extrinsics"][3:, 2] += 0.01
    with pytest.raises(CameraFileError, match=r"static camera"):
        from_interndata(cols)
    cols, *_ = interndata_frames()
    cols["states.gripper.position"][1] = 0.2
    with pytest.raises(TrajectoryError, match=r"Panda finger width \(metres\) in \[0, 0\.08\].*frame 1"):
        from_interndata(cols)
    cols, *_ = interndata_frames()
    del cols["timestamp"]
    with pytest.raises(TrajectoryError, match=r"timestamp.*fps="):
        from_interndata(cols)
    assert from_interndata(cols, fps=30.0)[0].fps == 30.0


# --------------------------------------------------------------------------- bad input through the plugin


def test_wrong_joint_count_or_names_are_refused(franka):
    cam = Camera(Intrinsics(500.0, 500.0, 63.5, 35.5, 128, 72), np.eye(4))
    six = Trajectory(JOINT_NAMES[:6], np.zeros((2, 6)), fps=10, gripper=np.full((2, 1), 0.04))
    with pytest.raises(TrajectoryError, match=r"the 7 joints of 'franka'.*panda_joint1.*missing \['panda_joint7'\]"):
        render_skeleton_video(franka, six, cam)
    kuka_names = tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8))
    with pytest.raises(TrajectoryError, match=r"unknown \['lbr_iiwa_joint_1'"):
        render_skeleton_video(franka, Trajectory(kuka_names, np.zeros((2, 7)), fps=10, gripper=np.zeros((2, 1))), cam)


def test_gripper_outside_its_range_is_refused(franka):
    cam = Camera(Intrinsics(500.0, 500.0, 63.5, 35.5, 128, 72), np.eye(4))
    with pytest.raises(TrajectoryError, match=r"gripper\[gripper\].*\[0, 0\.08\].*0\.5 at frame 0"):
        render_skeleton_video(franka, ready_traj(2, 0.5), cam)  # 0.5 looks like a normalised value, not metres


def test_camera_for_another_mount_or_embodiment_is_refused(franka):
    intr = Intrinsics(500.0, 500.0, 63.5, 35.5, 128, 72)
    with pytest.raises(CameraFileError, match=r"mount.*static \(mount: null\) for embodiment 'franka'.*panda_hand"):
        render_skeleton_video(franka, ready_traj(), Camera(intr, np.eye(4), mount_link="panda_hand"))
    with pytest.raises(CameraFileError, match=r"embodiment.*'franka'.*'kuka'"):
        render_skeleton_video(franka, ready_traj(), Camera(intr, np.eye(4), embodiment="kuka"))
