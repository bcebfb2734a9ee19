"""Golden images of the franka plugin: fixed configurations x fixed cameras at 512x288.

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_golden_franka.py --oscar-regen-golden``.
Tolerance: RMS 1.5 on 0-255 over the image, as for the toy arm: enough for
OpenCV anti-aliasing differences across builds, far below what a moved joint
or a changed gripper state gives (test_golden_tolerance_detects_a_small_change).
"""

import numpy as np
import pytest

from oscar_core import Camera, Intrinsics, Trajectory, load_camera, look_at, render_skeleton_video
from oscar_embodiments.franka import JOINT_NAMES, Franka

TOL = 1.5
SIZE = (512, 288)
CONFIGS = {
    # joints (rad), finger width (m)
    "ready_open": ([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785], 0.08),
    "reach_half_open": ([-0.019, 0.401, -0.155, -2.187, 0.113, 2.580, 0.785], 0.04),
    # arm stretched out: joint4 0.05 rad below its upper limit (-0.0698), joint7 0.1 rad from 2.8973
    "near_limits_closed": ([0.3, 1.2, 0.0, -0.12, 0.0, 1.4, 2.8], 0.0),
}


@pytest.fixture(scope="module")
def franka():
    return Franka()


@pytest.fixture(scope="module")
def cameras(franka):
    return {
        # the bundled example camera (DROID-like, 1280x720, resized to 512x288)
        "example": load_camera(franka.example_camera),
        # a wide-angle camera with radial distortion on the other side of the robot
        "side_distorted": Camera(
            Intrinsics(360.0, 360.0, 255.5, 143.5, 512, 288, distortion=(-0.15, 0.04, 0.001, -0.001)),
            look_at((0.45, 1.35, 0.75), (0.25, 0.0, 0.38)),
        ),
    }


def render_one(franka, config, camera):
    q, width = CONFIGS[config]
    traj = Trajectory(JOINT_NAMES, np.array([q]), fps=10, gripper=np.array([[width]]))
    return render_skeleton_video(franka, traj, camera, SIZE)[0]


@pytest.mark.parametrize("camera", ["example", "side_distorted"])
@pytest.mark.parametrize("config", sorted(CONFIGS))
def test_franka_golden(golden, franka, cameras, config, camera):
    golden.check(render_one(franka, config, cameras[camera]), f"franka_{config}_{camera}.png", tol=TOL)


def test_near_limits_config_is_within_limits(franka):
    lo, hi = franka.tree.limits()
    q = np.array(CONFIGS["near_limits_closed"][0])
    assert np.all(q > lo[:7]) and np.all(q < hi[:7])
    assert np.min(np.minimum(q - lo[:7], hi[:7] - q)) < 0.1


def test_golden_tolerance_detects_a_small_change(franka, cameras):
    from oscar_core.testing import compare_images

    base = render_one(franka, "reach_half_open", cameras["example"])
    CONFIGS["_nudged"] = ([0.001, 0.401, -0.155, -2.187, 0.113, 2.580, 0.785], 0.04)  # 0.02 rad of joint 1
    CONFIGS["_half_closed"] = (CONFIGS["reach_half_open"][0], 0.02)
    try:
        nudged = render_one(franka, "_nudged", cameras["example"])
        gripper = render_one(franka, "_half_closed", cameras["example"])
    finally:
        del CONFIGS["_nudged"], CONFIGS["_half_closed"]
    assert compare_images(nudged, base) > TOL
    assert compare_images(gripper, base) > TOL
