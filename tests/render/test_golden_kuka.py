"""Golden images of the kuka plugin: fixed configurations x fixed cameras at 512x288.

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_golden_kuka.py --oscar-regen-golden``.
Tolerance: RMS 1.5 on 0-255 over the image, as for the toy arm: enough for
OpenCV anti-aliasing differences across builds, far below what a moved joint
or a changed gripper state gives (test_golden_tolerance_detects_a_small_change).
"""

import numpy as np
import pytest

from oscar_core import Camera, Intrinsics, Trajectory, load_camera, look_at, render_skeleton_video
from oscar_embodiments.kuka import JOINT_NAMES, KukaIiwa14

TOL = 1.5
SIZE = (512, 288)
CONFIGS = {
    # A1..A7 (rad), Robotiq position (0 open .. 1 closed)
    "home_open": ([0.0, 0.3, 0.0, -1.5, 0.0, 1.3, 0.0], 0.0),
    "reach_half_open": ([0.253, 0.846, 0.084, -1.146, -0.069, 1.151, 0.0], 0.5),
    # A1 0.17 rad, A4 0.09 rad, A6 0.19 rad and A7 0.15 rad from their limits
    "near_limits_closed": ([2.8, 0.5, 0.0, -2.0, 0.5, 1.9, -2.9], 1.0),
}


@pytest.fixture(scope="module")
def kuka():
    return KukaIiwa14()


@pytest.fixture(scope="module")
def cameras(kuka):
    return {
        # the bundled example camera (RH20T-like: base -> camera, 1280x720, resized to 512x288)
        "example": load_camera(kuka.example_camera),
        # a wide-angle camera with radial distortion, on the robot's left
        "side_distorted": Camera(
            Intrinsics(300.0, 300.0, 255.5, 143.5, 512, 288, distortion=(-0.12, 0.03, 0.001, -0.001)),
            look_at((0.25, 1.55, 0.95), (0.1, 0.0, 0.6)),
        ),
    }


def render_one(kuka, config, camera):
    q, position = CONFIGS[config]
    traj = Trajectory(JOINT_NAMES, np.array([q]), fps=10, gripper=np.array([[position]]))
    return render_skeleton_video(kuka, traj, camera, SIZE)[0]


@pytest.mark.parametrize("camera", ["example", "side_distorted"])
@pytest.mark.parametrize("config", sorted(CONFIGS))
def test_kuka_golden(golden, kuka, cameras, config, camera):
    golden.check(render_one(kuka, config, cameras[camera]), f"kuka_{config}_{camera}.png", tol=TOL)


def test_near_limits_config_is_within_limits(kuka):
    lo, hi = kuka.tree.limits()
    q = np.array(CONFIGS["near_limits_closed"][0])
    assert np.all(q > lo[:7]) and np.all(q < hi[:7])
    assert np.min(np.minimum(q - lo[:7], hi[:7] - q)) < 0.1


def test_golden_tolerance_detects_a_small_change(kuka, cameras):
    from oscar_core.testing import compare_images

    base = render_one(kuka, "reach_half_open", cameras["example"])
    CONFIGS["_nudged"] = ([0.273, 0.846, 0.084, -1.146, -0.069, 1.151, 0.0], 0.5)  # 0.02 rad of A1
    CONFIGS["_more_closed"] = (CONFIGS["reach_half_open"][0], 0.75)
    try:
        nudged = render_one(kuka, "_nudged", cameras["example"])
        gripper = render_one(kuka, "_more_closed", cameras["example"])
    finally:
        del CONFIGS["_nudged"], CONFIGS["_more_closed"]
    assert compare_images(nudged, base) > TOL
    assert compare_images(gripper, base) > TOL
