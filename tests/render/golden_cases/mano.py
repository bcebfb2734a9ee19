"""Golden images of the hand embodiment (mano): the bundled example trajectory, three frames seen by its camera at
512x288. A case is ``(frame, right-hand shift in m along x)``, rendered as a one-frame trajectory (equal to that
frame of the whole video).

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_goldens.py -k mano --oscar-regen-golden``.
Tolerance as for the other embodiments: RMS 1.5 on 0-255; the right hand moved 4 mm to the side exceeds it
(test_tolerance_detects_a_small_change[mano]).
"""

import functools

import numpy as np

from oscar_core import get_embodiment, load_camera, load_trajectory, render_skeleton_video

from . import GoldenSuite

FRAMES = {"open": 0, "closing": 40, "grasp_lift": 80}


@functools.cache
def _example():
    mano = get_embodiment("mano")
    return mano, load_trajectory(mano.example_trajectory), load_camera(mano.example_camera)


def render(case) -> np.ndarray:
    t, shift = case
    mano, traj, cam = _example()
    kp = traj.keypoints[t : t + 1].copy()
    kp[:, 21:] += [shift, 0.0, 0.0]  # the right hand's 21 keypoints
    one = traj.replace(q=traj.q[t : t + 1], gripper=traj.gripper[t : t + 1], keypoints=kp)
    return render_skeleton_video(mano, one, cam, (512, 288))[0]


SUITE = GoldenSuite(
    "mano",
    {f"example_{name}": (t, 0.0) for name, t in sorted(FRAMES.items())},
    render,
    nudged=[((FRAMES["closing"], 0.0), (FRAMES["closing"], 0.004))],  # the right hand 4 mm to the side
)
