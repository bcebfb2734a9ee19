"""Golden images of the agibot_g1 plugin: 3 fixed configurations x 2 cameras at 384x288.

Cameras: the bundled head camera (mounted on ``head_link2``, 640x480 scaled to 384x288) and a static external camera
in front of the robot that sees all of it (a static camera fits any embodiment). tests/embodiments/test_agibot_g1.py
checks that the configurations are within the limits and that one is near a limit.

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_goldens.py -k agibot_g1 --oscar-regen-golden``.
Tolerance: RMS 1.5 on 0-255, as for the other embodiments; 0.02 rad at the left shoulder exceeds it
(test_tolerance_detects_a_small_change[agibot_g1]).
"""

import numpy as np

from oscar_core import Camera, Intrinsics, Trajectory, look_at
from oscar_embodiments.agibot_g1 import JOINTS, AgiBotG1

from . import bundled_camera, grid_suite

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
CAMERAS = {
    "external": Camera(Intrinsics(290.0, 290.0, 191.5, 143.5, 384, 288), look_at((2.1, 0.7, 1.5), (0.3, 0.0, 0.95))),
    "head": bundled_camera,
}


def trajectory(config) -> Trajectory:
    q, grip = config
    return Trajectory(JOINTS, np.array([q]), fps=30, gripper=np.array([grip]))


SHOULDER_NUDGED = list(CONFIGS["grasp_half_open"][0])
SHOULDER_NUDGED[JOINTS.index("idx21_arm_l_joint1")] += 0.02  # 0.02 rad at the left shoulder

SUITE = grid_suite(
    "agibot_g1",
    AgiBotG1,
    CONFIGS,
    CAMERAS,
    trajectory,
    (384, 288),
    nudged=[((CONFIGS["grasp_half_open"], "head"), ((SHOULDER_NUDGED, *CONFIGS["grasp_half_open"][1:]), "head"))],
)
