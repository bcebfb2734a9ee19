"""Golden images of the mesh condition: the toy arm (primitives), franka (DAE meshes from example-robot-data) and a
one-file plugin (SO-101, STL meshes from example-robot-data), one frame each at 512x288. A case is
``(embodiment, joints in its order, gripper signal, camera name)``.

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_goldens.py -k mesh --oscar-regen-golden``.
Tolerance: RMS 1.5 on 0-255 over the image, as for the skeleton goldens. The rasteriser has no anti-aliasing, so a
build that rounds differently flips a few silhouette pixels (each ~100-200 levels): 1.5 allows ~150 such pixels of
147,456, while a joint moved by 0.02 rad gives far more (test_tolerance_detects_a_small_change[mesh]).
"""

import functools
import sys

import numpy as np
from _paths import REPO

from oscar_core import Camera, Intrinsics, Registry, Trajectory, load_camera, look_at, render_mesh_video

from . import GoldenSuite

sys.path.insert(0, str(REPO / "examples" / "oscar-toyarm"))
from oscar_toyarm import ToyArm

SIZE = (512, 288)
CASES = {
    # name: (embodiment, joints in its order, gripper signal, camera name)
    "toyarm_reach_half_open_front": ("toyarm", [0.7, 0.9, 1.3, 0.7], 0.04, "toy_front"),
    "toyarm_home_open_side": ("toyarm", [0.0, 0.0, 0.0, 0.0], 0.08, "toy_side_distorted"),
    "franka_ready_open_example": ("franka", [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785], 0.08, "franka_example"),
    "franka_reach_closed_example": (
        "franka",
        [-0.019, 0.401, -0.155, -2.187, 0.113, 2.580, 0.785],
        0.0,
        "franka_example",
    ),
    # so101 joint order: wrist_roll, wrist_flex, elbow_flex, shoulder_lift, shoulder_pan
    "so101_reach_open_front": ("so101", [0.3, -0.4, 0.6, 0.6, 0.2], 1.0, "so101_front"),
}


@functools.cache
def _scene():
    """The embodiments and the cameras, built on the first render."""
    reg = Registry(plugin_paths=[str(REPO / "examples" / "one-file" / "so101.py")])
    embodiments = {"toyarm": ToyArm(), "franka": reg.get("franka"), "so101": reg.get("so101")}
    cameras = {
        "toy_front": Camera(
            Intrinsics(430.0, 430.0, 319.5, 179.5, 640, 360), look_at((1.05, -0.85, 0.7), (0.15, 0.0, 0.4))
        ),
        "toy_side_distorted": Camera(
            Intrinsics(300.0, 300.0, 255.5, 143.5, 512, 288, distortion=(-0.12, 0.03, 0.001, -0.001)),
            look_at((-0.15, 0.95, 0.55), (0.15, 0.0, 0.4)),
        ),
        "franka_example": load_camera(embodiments["franka"].example_camera),
        "so101_front": Camera(
            Intrinsics(330.0, 330.0, 255.5, 143.5, 512, 288), look_at((0.5, -0.5, 0.4), (0.12, 0.0, 0.05))
        ),
    }
    return embodiments, cameras


def render(case) -> np.ndarray:
    emb_name, q, grip, cam = case
    embodiments, cameras = _scene()
    emb = embodiments[emb_name]
    traj = Trajectory(emb.joint_names, np.array([q]), fps=10, gripper=np.array([[grip]]))
    return render_mesh_video(emb, traj, cameras[cam], SIZE)[0]


_BASE = CASES["franka_reach_closed_example"]
SUITE = GoldenSuite(
    "mesh",
    dict(sorted(CASES.items())),
    render,
    nudged=[(_BASE, (_BASE[0], [_BASE[1][0] + 0.02, *_BASE[1][1:]], *_BASE[2:]))],  # 0.02 rad of joint 1
)
