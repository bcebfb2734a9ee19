"""Regenerate the hand embodiment's bundled example trajectory and camera.

    python embodiments/mano/make_example.py

Both hands, seen by a head-mounted camera looking 55 degrees down (points
in its OpenCV frame: x right, y down, z forward), reach forward with flat open hands, close to a
grasp and lift; the left hand follows the right by a few frames and closes a
little less. 81 frames at 30 fps, from the procedural hand of
:mod:`oscar_embodiments.mano.synthetic` (no MANO files needed). Output goes to
``assets/``: ``example_trajectory.npz`` and ``example_camera.json``.
"""

from pathlib import Path

import numpy as np

from oscar_core import save_camera, save_trajectory
from oscar_embodiments.mano import egocentric_camera, trajectory_from_keypoints
from oscar_embodiments.mano.synthetic import hand_keypoints, place, rotation

ASSETS = Path(__file__).resolve().parent / "assets"
T, FPS = 81, 30.0


def smoothstep(t, t0, t1):
    s = np.clip((np.asarray(t, float) - t0) / (t1 - t0), 0.0, 1.0)
    return s * s * (3 - 2 * s)


PITCH = np.radians(55.0)  # the head-mounted camera looks 55 degrees down at the table


def head_to_camera(p: np.ndarray) -> np.ndarray:
    """Points in a level head frame (x right, y down, z forward) → the pitched camera's OpenCV frame."""
    c, s = np.cos(PITCH), np.sin(PITCH)
    R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])  # rows: camera x, y, z in head coordinates
    return p @ R.T


def hand_pose(side: str, inward: float, roll: float) -> np.ndarray:
    """Rotation hand frame → head frame: fingers forward (+z) and ``inward``
    radians towards the midline, back of the hand up (-y), rolled by ``roll``
    radians about the finger direction so the palms turn towards each other."""
    sign = 1.0 if side == "right" else -1.0  # the right hand is on the right (+x): inward is -x
    distal = np.array([-sign * np.sin(inward), 0.1, np.cos(inward)])
    distal /= np.linalg.norm(distal)
    dorsal = np.array([0.0, -1.0, 0.0])
    dorsal -= (dorsal @ distal) * distal
    dorsal /= np.linalg.norm(dorsal)
    R = np.stack([distal, np.cross(dorsal, distal), dorsal], axis=1)  # columns: hand x, y, z
    return rotation(distal, sign * roll) @ R


def one_hand(side: str, delay: int, grasp: float) -> np.ndarray:
    """(T, 21, 3) keypoints of one hand in the camera frame."""
    t = np.arange(T) - delay
    sign = 1.0 if side == "right" else -1.0
    reach = smoothstep(t, 0, 30)[:, None]
    lift = smoothstep(t, 55, 80)[:, None]
    start = np.array([sign * 0.14, 0.36, 0.10])
    target = np.array([sign * 0.10, 0.34, 0.20])
    wrist = start + reach * (target - start) + lift * np.array([0.0, -0.07, 0.02])
    curl = grasp * smoothstep(t, 25, 55)
    out = np.empty((T, 21, 3))
    for k in range(T):
        R = hand_pose(side, inward=0.3, roll=0.35 * smoothstep(t[k], 10, 45))
        out[k] = head_to_camera(place(hand_keypoints(curl[k], 0.8 * curl[k], side=side), R, wrist[k]))
    return out


def main():
    kp = np.stack([one_hand("left", delay=8, grasp=0.7), one_hand("right", delay=0, grasp=0.8)], axis=1)
    traj = trajectory_from_keypoints(kp, FPS)
    save_trajectory(traj, ASSETS / "example_trajectory.npz")
    save_camera(
        egocentric_camera(fx=420.0, fy=420.0, cx=319.5, cy=179.5, width=640, height=360), ASSETS / "example_camera.json"
    )
    print(f"wrote {T} frames and a camera to {ASSETS}")


if __name__ == "__main__":
    main()
