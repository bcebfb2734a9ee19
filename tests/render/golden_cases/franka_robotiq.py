"""Golden images of franka_robotiq (the Panda arm with a Robotiq 2F-85): 3 configurations x 2 cameras at 512x288.

The same arm configurations and cameras as franka.py (its bundled example camera, and the wide-angle distorted one
on the other side), the gripper given as DROID's signal (0 open .. 1 closed).

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_goldens.py -k franka_robotiq --oscar-regen-golden``.
Tolerance: RMS 1.5 on 0-255, as for the franka images; a gripper change exceeds it
(test_tolerance_detects_a_small_change[franka_robotiq]).
"""

import numpy as np

from oscar_core import Trajectory, get_embodiment
from oscar_embodiments.franka import JOINT_NAMES

from . import grid_suite
from .franka import CAMERAS

CONFIGS = {
    # joints (rad), Robotiq position (0 open .. 1 closed)
    "ready_open": ([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785], 0.0),
    "reach_half_closed": ([-0.019, 0.401, -0.155, -2.187, 0.113, 2.580, 0.785], 0.5),
    "near_limits_closed": ([0.3, 1.2, 0.0, -0.12, 0.0, 1.4, 2.8], 1.0),
}


def trajectory(config) -> Trajectory:
    q, position = config
    return Trajectory(JOINT_NAMES, np.array([q]), fps=10, gripper=np.array([[position]]))


SUITE = grid_suite(
    "franka_robotiq",
    lambda: get_embodiment("franka_robotiq"),
    CONFIGS,
    CAMERAS,
    trajectory,
    (512, 288),
    nudged=[
        (
            (CONFIGS["reach_half_closed"], "example"),
            ((CONFIGS["reach_half_closed"][0], 0.8), "example"),  # the gripper more closed
        ),
    ],
)
