"""Golden images of the agibot_g1 plugin: 3 fixed configurations x 2 cameras at 384x288.

Cameras: the bundled head camera (mounted on ``head_link2``, 640x480 scaled to
384x288) and a static external camera in front of the robot that sees all of
it (a static camera fits any embodiment).

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_golden_agibot_g1.py --oscar-regen-golden``.
Tolerance: RMS 1.5 on 0-255, as for the other embodiments.
"""

import numpy as np
import pytest

from oscar_core import Camera, Intrinsics, Trajectory, load_camera, look_at, render_skeleton_video
from oscar_core.testing import compare_images
from oscar_embodiments.agibot_g1 import JOINTS, AgiBotG1

TOL = 1.5
SIZE = (384, 288)
READY_L = [1.872, -0.959, -2.46, -1.45, 1.913, 1.476, 0.028]
GRASP_L = [1.813, -1.166, -2.255, -1.337, 2.057, 1.303, 0.807]
READY_R = [-v for v in READY_L]
CONFIGS = {
    # waist lift (m), waist pitch, head yaw, head pitch, left arm, right arm; grippers 0 open .. 1 closed
    "ready_open": ([0.15, 0.20, 0.0, 0.35] + READY_L + READY_R, [0.0, 0.0]),
    "grasp_half_open": ([0.15, 0.22, 0.12, 0.50] + GRASP_L + READY_R, [0.5, 0.0]),
    # waist lift 0.01 m below its limit (0.55), head pitch 0.02 rad below its limit (0.5236),
    # left elbow 0.02 rad from its limit (-1.48), both grippers closed
    "limits_closed": ([0.54, 0.10, 0.0, 0.50] + [1.6, -0.9, -2.4, -1.46, 1.9, 1.4, 0.0] + READY_R, [1.0, 1.0]),
}


EXTERNAL = Camera(Intrinsics(290.0, 290.0, 191.5, 143.5, 384, 288), look_at((2.1, 0.7, 1.5), (0.3, 0.0, 0.95)))


@pytest.fixture(scope="module")
def g1():
    return AgiBotG1()


def trajectory(config):
    q, grip = CONFIGS[config]
    return Trajectory(JOINTS, np.array([q]), fps=30, gripper=np.array([grip]))


def render_one(g1, config, camera_name):
    traj = trajectory(config)
    if camera_name == "head":
        return render_skeleton_video(g1, traj, load_camera(g1.example_camera), SIZE)[0]
    return render_skeleton_video(g1, traj, EXTERNAL)[0]


@pytest.mark.parametrize("camera_name", ["external", "head"])
@pytest.mark.parametrize("config", sorted(CONFIGS))
def test_agibot_g1_golden(golden, g1, config, camera_name):
    golden.check(render_one(g1, config, camera_name), f"agibot_g1_{config}_{camera_name}.png", tol=TOL)


def test_configs_are_within_limits_and_one_is_near_a_limit(g1):
    lo, hi = g1.tree.limits()
    keep = [g1.tree.joint_names.index(n) for n in JOINTS]
    lo, hi = lo[keep], hi[keep]
    for q, _ in CONFIGS.values():
        assert np.all((np.array(q) >= lo) & (np.array(q) <= hi))
    q = np.array(CONFIGS["limits_closed"][0])
    assert np.min(np.minimum(q - lo, hi - q)) <= 0.02


def test_golden_tolerance_detects_a_small_change(g1):
    base = render_one(g1, "grasp_half_open", "head")
    q, grip = CONFIGS["grasp_half_open"]
    nudged_q = list(q)
    nudged_q[JOINTS.index("idx21_arm_l_joint1")] += 0.02  # 0.02 rad at the left shoulder
    CONFIGS["_nudged"] = (nudged_q, grip)
    try:
        nudged = render_one(g1, "_nudged", "head")
    finally:
        del CONFIGS["_nudged"]
    assert compare_images(nudged, base) > TOL
