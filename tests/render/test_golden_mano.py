"""Golden images of the hand embodiment: the bundled example, three frames x its camera.

Regenerate (then look at the PNGs before committing) with
``python -m pytest tests/render/test_golden_mano.py --oscar-regen-golden``.
Tolerance as for the other embodiments: RMS 1.5 on 0-255.
"""

import pytest

from oscar_core import get_embodiment, load_camera, load_trajectory, render_skeleton_video
from oscar_core.testing import compare_images

TOL = 1.5
FRAMES = {"open": 0, "closing": 40, "grasp_lift": 80}


@pytest.fixture(scope="module")
def rendered():
    mano = get_embodiment("mano")
    traj = load_trajectory(mano.example_trajectory)
    cam = load_camera(mano.example_camera)
    video = render_skeleton_video(mano, traj, cam, (512, 288))
    return mano, traj, cam, video


@pytest.mark.parametrize("name", sorted(FRAMES))
def test_mano_golden(golden, rendered, name):
    golden.check(rendered[3][FRAMES[name]], f"mano_example_{name}.png", tol=TOL)


def test_golden_tolerance_detects_a_small_change(rendered):
    mano, traj, cam, video = rendered
    t = FRAMES["closing"]
    kp = traj.keypoints[t : t + 1].copy()
    kp[:, 21:] += [0.004, 0.0, 0.0]  # the right hand 4 mm to the side
    one = traj.replace(q=traj.q[t : t + 1], gripper=traj.gripper[t : t + 1], keypoints=kp)
    assert compare_images(render_skeleton_video(mano, one, cam, (512, 288))[0], video[t]) > TOL
