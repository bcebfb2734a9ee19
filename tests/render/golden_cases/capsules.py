"""Golden images of the ``capsules`` condition for the embodiments without visual meshes (kuka, hsr, agibot_g1,
franka_robotiq) and franka: frames 0 and the middle of each plugin's example trajectory (stacked vertically), seen by
its example camera at 512x288. A case is ``(embodiment name, nudge)``: the nudge (rad) is added to the first joint.

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_goldens.py -k capsules --oscar-regen-golden``. Tolerance: RMS 1.5 on 0-255, as
for the mesh goldens (the same rasteriser, no anti-aliasing); a joint moved by 0.02 rad exceeds it
(test_tolerance_detects_a_small_change[capsules]).
"""

import functools

import numpy as np

from oscar_core import Registry, load_trajectory
from oscar_core.render.capsules import render_capsule_video

from . import GoldenSuite

SIZE = (512, 288)
NAMES = ("kuka", "hsr", "agibot_g1", "franka_robotiq", "franka")


@functools.cache
def _registry() -> Registry:
    return Registry()


def render(case) -> np.ndarray:
    name, nudge = case
    emb = _registry().get(name)
    traj = emb.check_trajectory(load_trajectory(emb.example_trajectory))
    cam = emb.load_camera(emb.example_camera)
    frames = [0, len(traj) // 2]
    if nudge:
        q = traj.q.copy()
        q[:, 0] += nudge
        traj = type(traj)(traj.joint_names, q, traj.fps, traj.gripper, traj.gripper_names, base_pose=traj.base_pose)
    video = render_capsule_video(emb, traj, cam, SIZE)
    return np.concatenate([video[t] for t in frames], axis=0)


SUITE = GoldenSuite(
    "capsules",
    {f"{name}_example": (name, 0.0) for name in NAMES},
    render,
    nudged=[(("kuka", 0.0), ("kuka", 0.02))],
)
