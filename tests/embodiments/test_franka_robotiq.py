"""franka_robotiq: the Panda arm with a Robotiq 2F-85 (DROID, RoboArena).

Known answers: the arm is the franka embodiment's, link for link; the
Robotiq's published stroke is 85 mm (finger pads 6.35 mm thick in the
ROS-Industrial description); the coupling puts the gripper base 11 mm
beyond the flange, turned like the Franka Hand.
"""

import numpy as np
import pytest

from oscar_core import Trajectory, get_embodiment, load_camera, load_trajectory, render_skeleton_video
from oscar_embodiments.franka import JOINT_NAMES
from oscar_embodiments.franka.adapters import from_droid
from oscar_embodiments.franka.robotiq import (
    COUPLING_LENGTH,
    FLANGE,
    ROBOTIQ_CLOSED,
    FrankaRobotiq,
    build_franka_robotiq_tree,
)

READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
PAD_THICKNESS = 0.00635  # m, <box size="0.022 0.00635 0.0375"/> of the description's finger pad


@pytest.fixture(scope="module")
def robotiq():
    return get_embodiment("franka_robotiq")


def pads(emb, q, signal):
    t = emb.check_trajectory(
        Trajectory(JOINT_NAMES, np.atleast_2d(q), 10, gripper=np.array(signal, float).reshape(-1, 1))
    )
    P = emb.fk(
        emb.full_configuration(t), links=["robotiq_base", "left_inner_finger_pad", "right_inner_finger_pad", FLANGE]
    ).numpy()
    return P


def test_is_registered_with_the_arm_joints_and_one_driven_finger(robotiq):
    assert isinstance(robotiq, FrankaRobotiq) and robotiq.problems() == []
    assert robotiq.joint_names == JOINT_NAMES  # trajectories are the franka's
    assert robotiq.tree.joint_names == JOINT_NAMES + ("finger_joint",)
    mimics = {j.name: j.mimic for j in robotiq.tree.joints if j.mimic}
    assert mimics == {
        "right_outer_knuckle_joint": ("finger_joint", 1.0, 0.0),
        "left_inner_finger_joint": ("finger_joint", -1.0, 0.0),
        "right_inner_finger_joint": ("finger_joint", -1.0, 0.0),
    }
    # no Franka Hand left below the flange
    assert not [l for l in robotiq.tree.links if "hand" in l or l.startswith("panda_") and "finger" in l]


def test_arm_is_the_franka_arm(robotiq):
    franka = get_embodiment("franka")
    rng = np.random.default_rng(0)
    lo, hi = franka.tree.limits()
    q = rng.uniform(lo[:7], hi[:7], (6, 7))
    links = [f"panda_link{i}" for i in range(9)]
    a = franka.fk(np.column_stack([q, np.zeros(6)]), links=links).numpy()
    b = robotiq.fk(np.column_stack([q, np.zeros(6)]), links=links).numpy()
    assert np.abs(a - b).max() < 1e-12


def test_coupling_offset_and_orientation(robotiq):
    P = pads(robotiq, READY, [0.0])[0]
    base, flange = P[0], P[3]
    rel = np.linalg.inv(flange) @ base
    assert np.allclose(rel[:3, 3], [0, 0, COUPLING_LENGTH], atol=1e-12)
    # turned like the Franka Hand (panda_hand_joint rpy 0 0 -pi/4): the jaws close along the same axis
    hand = get_embodiment("franka").fk(np.array([READY + [0.04]]), links=["panda_hand"]).numpy()[0, 0]
    assert np.allclose(base[:3, :3], hand[:3, :3], atol=1e-9)


def test_stroke_is_the_robotiq_85_mm(robotiq):
    P = pads(robotiq, np.tile(READY, (3, 1)), [0.0, 0.5, 1.0])
    gap = np.linalg.norm(P[:, 1, :3, 3] - P[:, 2, :3, 3], axis=1) - PAD_THICKNESS  # between the pad surfaces
    assert gap[0] == pytest.approx(0.085, abs=0.002)  # open: the published 85 mm stroke
    assert gap[2] == pytest.approx(0.0, abs=0.002)  # closed at finger_joint = 0.8 rad: the pads meet
    assert gap[0] > gap[1] > gap[2]
    # the jaw closes along the base's y axis and the fingertips stay centred on its z axis
    for p in P:
        mid = np.linalg.inv(p[0]) @ np.append((p[1, :3, 3] + p[2, :3, 3]) / 2, 1.0)
        assert np.abs(mid[:2]).max() < 1e-9 and 0.12 < mid[2] < 0.15
        across = p[0][:3, :3].T @ (p[1, :3, 3] - p[2, :3, 3])
        assert abs(across[0]) < 1e-9 and abs(across[1]) > 0.005


def test_signal_drives_the_finger_joint_linearly(robotiq):
    t = robotiq.check_trajectory(Trajectory(JOINT_NAMES, np.tile(READY, (3, 1)), 10, gripper=[[0.0], [0.25], [1.0]]))
    assert np.allclose(robotiq.full_configuration(t)[:, 7], [0.0, 0.25 * ROBOTIQ_CLOSED, ROBOTIQ_CLOSED])
    assert np.allclose(robotiq.gripper_openness(t.gripper)[:, 0], [1.0, 0.75, 0.0])  # 0 = open (DROID)


def test_tree_is_rebuilt_with_another_coupling():
    tree = build_franka_robotiq_tree(coupling_length=0.05, coupling_yaw=0.0)
    assert tree.joint("robotiq_coupling_joint").origin[2, 3] == pytest.approx(0.05)
    assert np.allclose(tree.joint("robotiq_coupling_joint").origin[:3, :3], np.eye(3))


def test_droid_episode_renders_with_the_robotiq(robotiq):
    T = 6
    pos = np.linspace(0, 1, T)
    record = {
        "observation": {
            "robot_state": {"joint_positions": np.tile(READY, (T, 1)), "gripper_position": pos},
            "camera_extrinsics": {"cam_left": np.tile([1.05, -1.5, 0.85, -2.0, 0.0, 0.5], (T, 1))},
            "camera_intrinsics": {"cam_left": np.array([[700.0, 0, 639.5], [0, 700.0, 359.5], [0, 0, 1]])},
        }
    }
    traj, cam = from_droid(record, "cam_left")
    assert cam.embodiment == "franka_robotiq"
    video = render_skeleton_video(robotiq, traj, cam, (256, 144), camera_source="droid")
    assert video.shape == (T, 144, 256, 3) and video.max() > 0
    assert not np.array_equal(video[0], video[-1])  # only the gripper changed: the jaw and indicator moved
    with pytest.raises(Exception, match="embodiment"):  # a camera made for the Robotiq arm is refused for the hand
        render_skeleton_video(get_embodiment("franka"), traj, cam)


def test_example_matches_the_franka_example(robotiq):
    franka = get_embodiment("franka")
    a = load_trajectory(franka.example_trajectory)
    b = load_trajectory(robotiq.example_trajectory)
    assert np.array_equal(a.q, b.q)
    assert np.allclose(b.gripper[:, 0], np.clip(1 - a.gripper[:, 0] / 0.085, 0, 1))
    ca, cb = load_camera(franka.example_camera), load_camera(robotiq.example_camera)
    assert np.array_equal(ca.extrinsic, cb.extrinsic) and cb.embodiment == "franka_robotiq"
