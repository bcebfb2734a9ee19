"""Golden images of the hsr plugin: 3 fixed configurations x 2 cameras at 384x288.

Cameras: the bundled head RGB-D camera (mounted on ``head_rgbd_sensor_link``, 640x480 scaled to 384x288) and a
static external camera that sees the whole robot, including its base pose (a static camera fits any embodiment).
tests/embodiments/test_hsr.py checks that the configurations are within the limits (one near a limit) and that the
base pose moves the external view but not the head view.

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_goldens.py -k hsr --oscar-regen-golden``.
Tolerance: RMS 1.5 on 0-255, as for the other embodiments; 0.02 rad at the shoulder exceeds it
(test_tolerance_detects_a_small_change[hsr]).
"""

import numpy as np

from oscar_core import Camera, Intrinsics, Trajectory, look_at
from oscar_embodiments.hsr import HAND_RANGE, HSR, JOINTS, base_pose_from_xy_yaw

from . import bundled_camera, grid_suite

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
CAMERAS = {
    "external": Camera(Intrinsics(330.0, 330.0, 191.5, 143.5, 384, 288), look_at((1.7, -1.1, 1.3), (0.25, 0.0, 0.75))),
    "head": bundled_camera,
}


def trajectory(config) -> Trajectory:
    q, hand, (x, y, yaw) = config
    return Trajectory(
        JOINTS, np.array([q]), fps=10, gripper=np.array([[hand]]), base_pose=base_pose_from_xy_yaw(x, y, yaw)
    )


SHOULDER_NUDGED = list(CONFIGS["reach_half_open"][0])
SHOULDER_NUDGED[JOINTS.index("arm_flex_joint")] += 0.02  # 0.02 rad at the shoulder

SUITE = grid_suite(
    "hsr",
    HSR,
    CONFIGS,
    CAMERAS,
    trajectory,
    (384, 288),
    nudged=[((CONFIGS["reach_half_open"], "head"), ((SHOULDER_NUDGED, *CONFIGS["reach_half_open"][1:]), "head"))],
)
