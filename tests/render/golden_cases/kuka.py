"""Golden images of the kuka plugin: 3 fixed configurations x 2 fixed cameras at 512x288.

Cameras: the bundled example camera (RH20T-like: base -> camera, 1280x720, resized to 512x288) and a wide-angle
camera with radial distortion, on the robot's left. The near-limits configuration is checked to be within the
limits in tests/embodiments/test_kuka.py.

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_goldens.py -k kuka --oscar-regen-golden``.
Tolerance: RMS 1.5 on 0-255 over the image, as for the toy arm: enough for OpenCV anti-aliasing differences across
builds, far below what a moved joint or a changed gripper state gives (the nudges below,
test_tolerance_detects_a_small_change[kuka]).
"""

import numpy as np

from oscar_core import Camera, Intrinsics, Trajectory, look_at
from oscar_embodiments.kuka import JOINT_NAMES, KukaIiwa14

from . import bundled_camera, grid_suite

CONFIGS = {
    # A1..A7 (rad), Robotiq position (0 open .. 1 closed)
    "home_open": ([0.0, 0.3, 0.0, -1.5, 0.0, 1.3, 0.0], 0.0),
    "reach_half_open": ([0.253, 0.846, 0.084, -1.146, -0.069, 1.151, 0.0], 0.5),
    # A1 0.17 rad, A4 0.09 rad, A6 0.19 rad and A7 0.15 rad from their limits
    "near_limits_closed": ([2.8, 0.5, 0.0, -2.0, 0.5, 1.9, -2.9], 1.0),
}
CAMERAS = {
    "example": bundled_camera,
    "side_distorted": Camera(
        Intrinsics(300.0, 300.0, 255.5, 143.5, 512, 288, distortion=(-0.12, 0.03, 0.001, -0.001)),
        look_at((0.25, 1.55, 0.95), (0.1, 0.0, 0.6)),
    ),
}


def trajectory(config) -> Trajectory:
    q, position = config
    return Trajectory(JOINT_NAMES, np.array([q]), fps=10, gripper=np.array([[position]]))


BASE = (CONFIGS["reach_half_open"], "example")
SUITE = grid_suite(
    "kuka",
    KukaIiwa14,
    CONFIGS,
    CAMERAS,
    trajectory,
    (512, 288),
    nudged=[
        (BASE, (([0.273, 0.846, 0.084, -1.146, -0.069, 1.151, 0.0], 0.5), "example")),  # 0.02 rad of A1
        (BASE, ((CONFIGS["reach_half_open"][0], 0.75), "example")),  # the gripper more closed
    ],
)
