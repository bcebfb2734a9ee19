"""Golden images of the franka plugin: 3 fixed configurations x 2 fixed cameras at 512x288.

Cameras: the bundled example camera (DROID-like, 1280x720, resized to 512x288) and a wide-angle camera with radial
distortion on the other side of the robot. The near-limits configuration is checked to be within the limits in
tests/embodiments/test_franka.py; franka_robotiq.py uses the same arm configurations and cameras.

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_goldens.py -k "franka and not robotiq" --oscar-regen-golden``.
Tolerance: RMS 1.5 on 0-255 over the image, as for the toy arm: enough for OpenCV anti-aliasing differences across
builds, far below what a moved joint or a changed gripper state gives (the nudges below,
test_tolerance_detects_a_small_change[franka]).
"""

import numpy as np

from oscar_core import Camera, Intrinsics, Trajectory, look_at
from oscar_embodiments.franka import JOINT_NAMES, Franka

from . import bundled_camera, grid_suite

CONFIGS = {
    # joints (rad), finger width (m)
    "ready_open": ([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785], 0.08),
    "reach_half_open": ([-0.019, 0.401, -0.155, -2.187, 0.113, 2.580, 0.785], 0.04),
    # arm stretched out: joint4 0.05 rad below its upper limit (-0.0698), joint7 0.1 rad from 2.8973
    "near_limits_closed": ([0.3, 1.2, 0.0, -0.12, 0.0, 1.4, 2.8], 0.0),
}
CAMERAS = {
    "example": bundled_camera,
    "side_distorted": Camera(
        Intrinsics(360.0, 360.0, 255.5, 143.5, 512, 288, distortion=(-0.15, 0.04, 0.001, -0.001)),
        look_at((0.45, 1.35, 0.75), (0.25, 0.0, 0.38)),
    ),
}


def trajectory(config) -> Trajectory:
    q, width = config
    return Trajectory(JOINT_NAMES, np.array([q]), fps=10, gripper=np.array([[width]]))


BASE = (CONFIGS["reach_half_open"], "example")
SUITE = grid_suite(
    "franka",
    Franka,
    CONFIGS,
    CAMERAS,
    trajectory,
    (512, 288),
    nudged=[
        (BASE, (([0.001, 0.401, -0.155, -2.187, 0.113, 2.580, 0.785], 0.04), "example")),  # 0.02 rad of joint 1
        (BASE, ((CONFIGS["reach_half_open"][0], 0.02), "example")),  # the gripper half closed
    ],
)
