"""Golden images of franka_robotiq (the Panda arm with a Robotiq 2F-85) at 512x288.

The same arm configurations and cameras as tests/render/test_golden_franka.py, the
gripper given as DROID's signal (0 open .. 1 closed). Regenerate (then look
at the PNGs before committing) with
``python -m pytest tests/render/test_golden_franka_robotiq.py --oscar-regen-golden``.
Tolerance: RMS 1.5 on 0-255, as for the franka images.
"""

import numpy as np
import pytest

from oscar_core import Camera, Intrinsics, Trajectory, get_embodiment, load_camera, look_at, render_skeleton_video
from oscar_embodiments.franka import JOINT_NAMES

TOL = 1.5
SIZE = (512, 288)
CONFIGS = {
    # joints (rad), Robotiq position (0 open .. 1 closed)
    "ready_open": ([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785], 0.0),
    "reach_half_closed": ([-0.019, 0.401, -0.155, -2.187, 0.113, 2.580, 0.785], 0.5),
    "near_limits_closed": ([0.3, 1.2, 0.0, -0.12, 0.0, 1.4, 2.8], 1.0),
}


@pytest.fixture(scope="module")
def robotiq():
    return get_embodiment("franka_robotiq")


@pytest.fixture(scope="module")
def cameras(robotiq):
    return {
        "example": load_camera(robotiq.example_camera),
        "side_distorted": Camera(
            Intrinsics(360.0, 360.0, 255.5, 143.5, 512, 288, distortion=(-0.15, 0.04, 0.001, -0.001)),
            look_at((0.45, 1.35, 0.75), (0.25, 0.0, 0.38)),
        ),
    }


def render_one(emb, config, camera):
    q, position = CONFIGS[config]
    traj = Trajectory(JOINT_NAMES, np.array([q]), fps=10, gripper=np.array([[position]]))
    return render_skeleton_video(emb, traj, camera, SIZE)[0]


@pytest.mark.parametrize("camera", ["example", "side_distorted"])
@pytest.mark.parametrize("config", sorted(CONFIGS))
def test_franka_robotiq_golden(golden, robotiq, cameras, config, camera):
    golden.check(render_one(robotiq, config, cameras[camera]), f"franka_robotiq_{config}_{camera}.png", tol=TOL)


def test_golden_tolerance_detects_a_gripper_change(robotiq, cameras):
    from oscar_core.testing import compare_images

    base = render_one(robotiq, "reach_half_closed", cameras["example"])
    CONFIGS["_closed"] = (CONFIGS["reach_half_closed"][0], 0.8)
    try:
        closed = render_one(robotiq, "_closed", cameras["example"])
    finally:
        del CONFIGS["_closed"]
    assert compare_images(closed, base) > TOL
