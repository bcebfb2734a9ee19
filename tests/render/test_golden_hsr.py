"""Golden images of the hsr plugin: 3 fixed configurations x 2 cameras at 384x288.

Cameras: the bundled head RGB-D camera (mounted on ``head_rgbd_sensor_link``,
640x480 scaled to 384x288) and a static external camera that sees the whole
robot, including its base pose (a static camera fits any embodiment).

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_golden_hsr.py --oscar-regen-golden``.
Tolerance: RMS 1.5 on 0-255, as for the other embodiments.
"""

import numpy as np
import pytest

from oscar_core import Camera, Intrinsics, Trajectory, load_camera, look_at, render_skeleton_video
from oscar_core.testing import compare_images
from oscar_embodiments.hsr import HAND_RANGE, HSR, JOINTS, base_pose_from_xy_yaw

TOL = 1.5
SIZE = (384, 288)
HALF_OPEN = 0.62  # rad: openness 0.5 (fingertips meet at 0, fully open at 1.24)
CONFIGS = {
    # arm lift (m), arm flex, arm roll, wrist flex, wrist roll, head pan, head tilt; hand_motor_joint (rad);
    # base x, y (m), yaw (rad)
    "carry_closed": ([0.05, -0.40, 0.0, -1.20, 0.0, 0.0, -0.50], 0.0, (0.0, 0.0, 0.0)),
    "reach_half_open": ([0.12, -1.50, 0.0, -0.05, 0.0, 0.05, -0.70], HALF_OPEN, (0.15, 0.02, 0.08)),
    # arm lift 0.01 m below its limit (0.69), arm flex 0.05 rad from 0, wrist flex 0.02 rad from 1.22,
    # head tilt 0.02 rad from 0.52 (looking up at the hand), hand fully open
    "limits_open": ([0.68, -0.05, 0.5, 1.20, 0.0, 0.3, 0.50], HAND_RANGE[1], (-0.2, 0.1, -0.5)),
}


EXTERNAL = Camera(Intrinsics(330.0, 330.0, 191.5, 143.5, 384, 288), look_at((1.7, -1.1, 1.3), (0.25, 0.0, 0.75)))


@pytest.fixture(scope="module")
def hsr():
    return HSR()


def trajectory(config):
    q, hand, (x, y, yaw) = CONFIGS[config]
    return Trajectory(
        JOINTS, np.array([q]), fps=10, gripper=np.array([[hand]]), base_pose=base_pose_from_xy_yaw(x, y, yaw)
    )


def render_one(hsr, config, camera_name):
    traj = trajectory(config)
    if camera_name == "head":
        return render_skeleton_video(hsr, traj, load_camera(hsr.example_camera), SIZE)[0]
    return render_skeleton_video(hsr, traj, EXTERNAL)[0]


@pytest.mark.parametrize("camera_name", ["external", "head"])
@pytest.mark.parametrize("config", sorted(CONFIGS))
def test_hsr_golden(golden, hsr, config, camera_name):
    golden.check(render_one(hsr, config, camera_name), f"hsr_{config}_{camera_name}.png", tol=TOL)


def test_configs_are_within_limits_and_one_is_near_a_limit(hsr):
    lo, hi = hsr.tree.limits()
    keep = [hsr.tree.joint_names.index(n) for n in JOINTS]
    lo, hi = lo[keep], hi[keep]
    for q, hand, _ in CONFIGS.values():
        assert np.all((np.array(q) >= lo) & (np.array(q) <= hi))
        assert HAND_RANGE[0] <= hand <= HAND_RANGE[1]
    q = np.array(CONFIGS["limits_open"][0])
    assert np.min(np.minimum(q - lo, hi - q)) <= 0.02


def test_base_pose_moves_the_external_view_but_not_the_head_view(hsr):
    q, hand, _ = CONFIGS["reach_half_open"]
    views = {}
    for name, pose in (("origin", (0.0, 0.0, 0.0)), ("moved", (0.3, -0.2, 0.4))):
        CONFIGS["_base"] = (q, hand, pose)
        try:
            views[name] = (render_one(hsr, "_base", "head"), render_one(hsr, "_base", "external"))
        finally:
            del CONFIGS["_base"]
    assert compare_images(views["origin"][0], views["moved"][0]) == 0.0
    assert compare_images(views["origin"][1], views["moved"][1]) > TOL


def test_golden_tolerance_detects_a_small_change(hsr):
    base = render_one(hsr, "reach_half_open", "head")
    q, hand, pose = CONFIGS["reach_half_open"]
    nudged = list(q)
    nudged[JOINTS.index("arm_flex_joint")] += 0.02  # 0.02 rad at the shoulder
    CONFIGS["_nudged"] = (nudged, hand, pose)
    try:
        moved = render_one(hsr, "_nudged", "head")
    finally:
        del CONFIGS["_nudged"]
    assert compare_images(moved, base) > TOL
