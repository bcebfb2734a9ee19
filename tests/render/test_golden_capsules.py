"""Golden images of the ``capsules`` condition for the embodiments without visual meshes (kuka, hsr,
agibot_g1, franka_robotiq) and franka: frames 0 and the middle of each plugin's example trajectory, seen by
its example camera at 512x288.

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_golden_capsules.py --oscar-regen-golden``. Tolerance: RMS 1.5 on 0-255,
as for the mesh goldens (the same rasteriser, no anti-aliasing); a joint moved by 0.02 rad exceeds it
(test_capsule_golden_tolerance_detects_a_small_change).
"""

import numpy as np
import pytest

from oscar_core import Registry, load_trajectory
from oscar_core.render.capsules import render_capsule_video
from oscar_core.testing import compare_images

TOL = 1.5
SIZE = (512, 288)
NAMES = ("kuka", "hsr", "agibot_g1", "franka_robotiq", "franka")


@pytest.fixture(scope="module")
def registry():
    return Registry()


def render_case(registry, name, nudge: float = 0.0):
    emb = registry.get(name)
    traj = emb.check_trajectory(load_trajectory(emb.example_trajectory))
    cam = emb.load_camera(emb.example_camera)
    frames = [0, len(traj) // 2]
    if nudge:
        q = traj.q.copy()
        q[:, 0] += nudge
        traj = type(traj)(traj.joint_names, q, traj.fps, traj.gripper, traj.gripper_names, base_pose=traj.base_pose)
    video = render_capsule_video(emb, traj, cam, SIZE)
    return np.concatenate([video[t] for t in frames], axis=0)


@pytest.mark.parametrize("name", NAMES)
def test_capsule_golden(golden, registry, name):
    golden.check(render_case(registry, name), f"capsules_{name}_example.png", tol=TOL)


def test_capsule_golden_tolerance_detects_a_small_change(registry):
    assert compare_images(render_case(registry, "kuka", nudge=0.02), render_case(registry, "kuka")) > TOL
