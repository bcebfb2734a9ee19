"""Golden images of the example plugin: fixed configurations x fixed cameras.

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_golden_toyarm.py --oscar-regen-golden``.
Tolerance: RMS 1.5 on 0-255 over the image, enough for OpenCV anti-aliasing
differences across builds, far below what a moved point or a changed colour
gives (see test_golden_tolerance_detects_a_small_change).
"""

import sys

import numpy as np
import pytest
from _paths import REPO

from oscar_core import Camera, Intrinsics, Trajectory, look_at, render_skeleton_video
from oscar_core.testing import compare_images

sys.path.insert(0, str(REPO / "examples" / "oscar-toyarm"))
from oscar_toyarm import ToyArm

TOL = 1.5
ARM = ("base_yaw", "shoulder", "elbow", "wrist_pitch")
CONFIGS = {
    "home_open": ([0.0, 0.0, 0.0, 0.0], 0.08),
    "reach_half_open": ([0.7, 0.9, 1.3, 0.7], 0.04),
    "elbow_near_limit_closed": ([-1.2, -0.6, -2.45, 1.2], 0.0),
}


CAMERAS = {
    "front": Camera(Intrinsics(430.0, 430.0, 319.5, 179.5, 640, 360), look_at((1.05, -0.85, 0.7), (0.15, 0.0, 0.4))),
    # a wide-angle side camera with radial distortion
    "side_distorted": Camera(
        Intrinsics(300.0, 300.0, 255.5, 143.5, 512, 288, distortion=(-0.12, 0.03, 0.001, -0.001)),
        look_at((-0.15, 0.95, 0.55), (0.15, 0.0, 0.4)),
    ),
}


@pytest.fixture(scope="module")
def toyarm():
    return ToyArm()


def render_one(toyarm, config, camera):
    q, width = CONFIGS[config]
    traj = Trajectory(ARM, np.array([q]), fps=10, gripper=np.array([[width]]))
    return render_skeleton_video(toyarm, traj, camera, (512, 288))[0]


@pytest.mark.parametrize("camera", sorted(CAMERAS))
@pytest.mark.parametrize("config", sorted(CONFIGS))
def test_toyarm_golden(golden, toyarm, config, camera):
    golden.check(render_one(toyarm, config, CAMERAS[camera]), f"toyarm_{config}_{camera}.png", tol=TOL)


def test_golden_tolerance_detects_a_small_change(toyarm):
    base = render_one(toyarm, "reach_half_open", CAMERAS["front"])
    CONFIGS["_nudged"] = ([0.72, 0.9, 1.3, 0.7], 0.04)  # 0.02 rad of base yaw
    try:
        nudged = render_one(toyarm, "_nudged", CAMERAS["front"])
    finally:
        del CONFIGS["_nudged"]
    assert compare_images(nudged, base) > TOL
