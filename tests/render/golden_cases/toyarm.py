"""Golden images of the example plugin (the toy arm): 3 fixed configurations x 2 fixed cameras at 512x288.

Cameras: a front camera (640x360, resized to 512x288) and a wide-angle side camera with radial distortion.

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_goldens.py -k "toyarm and not mesh" --oscar-regen-golden``.
Tolerance: RMS 1.5 on 0-255 over the image, enough for OpenCV anti-aliasing differences across builds, far below what
a moved point or a changed colour gives (test_tolerance_detects_a_small_change[toyarm]).
"""

import sys

import numpy as np
from _paths import REPO

from oscar_core import Camera, Intrinsics, Trajectory, look_at

from . import grid_suite

sys.path.insert(0, str(REPO / "examples" / "oscar-toyarm"))
from oscar_toyarm import ToyArm

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


def trajectory(config) -> Trajectory:
    q, width = config
    return Trajectory(ARM, np.array([q]), fps=10, gripper=np.array([[width]]))


SUITE = grid_suite(
    "toyarm",
    ToyArm,
    CONFIGS,
    CAMERAS,
    trajectory,
    (512, 288),
    nudged=[
        ((CONFIGS["reach_half_open"], "front"), (([0.72, 0.9, 1.3, 0.7], 0.04), "front")),  # 0.02 rad of base yaw
    ],
)
