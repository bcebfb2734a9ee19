"""A trajectory's gripper open/close signal through its embodiment: what training records per clip and what a
world model with a gripper signal is given at rollout, computed one way for both."""

from __future__ import annotations

import numpy as np

__all__ = ["trajectory_openness"]


def trajectory_openness(embodiment, trajectory) -> np.ndarray:
    """(T, G) float64 open/close signal in [0, 1] (1 = open) of a trajectory through its embodiment.

    Robots: each gripper's openness from its raw signal (``Embodiment.gripper_openness``); embodiments that read
    keypoints (hands) compute it in their ``frames`` (normalised fingertip flexion). (T, 0) for a body without
    grippers.
    """
    traj = embodiment.check_trajectory(trajectory)
    if embodiment.uses_kinematic_tree():
        return np.asarray(embodiment.gripper_openness(traj.gripper, traj.source), dtype=np.float64)
    return np.asarray(embodiment.frames(traj).openness, dtype=np.float64)
