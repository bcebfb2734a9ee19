"""Where a robot can reach: its joint box, open grippers, its end-effector, and its reach.

Shared by the toy world (motions, policies: :mod:`oscar_core.toyworld`), the capsule body
(:mod:`oscar_core.render.capsules`, whose sizes follow the reach) and the benchmark protocol's
forward-window check. Units: radians / metres for joints, metres in the world. ``emb`` is any object with the
members of :class:`Embodiment` (a plugin's :class:`oscar_core.plugin.embodiment.Embodiment` is one).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from .trajectory import Trajectory

__all__ = ["Embodiment", "joint_limits", "openness_to_signal", "end_effector", "ee_points", "open_fk", "reach_of"]


class _Gripper(Protocol):
    @property
    def signal_range(self) -> tuple[float, float]: ...

    @property
    def closed_at(self) -> str: ...


class Embodiment(Protocol):
    """What these functions read of a robot: the members of :class:`oscar_core.plugin.embodiment.Embodiment` they
    use (read-only), declared here so that kinematics, the floor below the plugin contract, needs nothing from it."""

    @property
    def tree(self) -> Any:
        """The kinematic tree: ``limits()`` → (lower, upper) arrays over ``tree.joint_names``."""

    @property
    def joint_names(self) -> Sequence[str]: ...

    @property
    def grippers(self) -> Sequence[_Gripper]: ...

    @property
    def gripper_names(self) -> Sequence[str]: ...

    def frames(self, traj: Trajectory) -> Any:
        """Skeleton ``points`` (T, K, 3) and ``gripper_points`` (T, G, 3), metres, of ``traj``."""


def joint_limits(emb: Embodiment, shrink: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """(J,) lower and upper limits of ``emb.joint_names`` (radians / metres), shrunk by ``shrink`` of the range;
    an unlimited joint spans [−π, π]."""
    lo, hi = emb.tree.limits()
    pos = {n: i for i, n in enumerate(emb.tree.joint_names)}
    idx = [pos[n] for n in emb.joint_names]
    lo, hi = lo[idx].astype(np.float64), hi[idx].astype(np.float64)
    lo = np.where(np.isfinite(lo), lo, -np.pi)
    hi = np.where(np.isfinite(hi), hi, np.pi)
    span = hi - lo
    return lo + shrink * span, hi - shrink * span


def openness_to_signal(emb: Embodiment, openness: np.ndarray) -> np.ndarray:
    """(T, G) openness in [0, 1] → (T, G) raw gripper signals in each gripper's ``signal_range``."""
    cols = []
    for i, g in enumerate(emb.grippers):
        lo, hi = g.signal_range
        o = openness[:, i]
        cols.append(lo + o * (hi - lo) if g.closed_at == "low" else hi - o * (hi - lo))
    return np.stack(cols, axis=1) if cols else np.zeros((openness.shape[0], 0))


def end_effector(emb: Embodiment, frames) -> np.ndarray:
    """(T, 3) end-effector of :meth:`Embodiment.frames`'s output, metres: the first gripper's indicator
    point, or the last skeleton point for an embodiment without grippers."""
    return frames.gripper_points[:, 0] if len(emb.grippers) else frames.points[:, -1]


def ee_points(emb: Embodiment, traj: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """World positions of the skeleton points (T, K, 3) and of the end-effector (T, 3), metres."""
    fr = emb.frames(traj)
    return fr.points, end_effector(emb, fr)


def open_fk(emb: Embodiment, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Skeleton points (N, K, 3) and end-effectors (N, 3) of N configurations ``q`` (N, J), grippers open."""
    gripper = openness_to_signal(emb, np.ones((len(q), len(emb.grippers))))
    return ee_points(emb, Trajectory(emb.joint_names, q, 10.0, gripper, emb.gripper_names or None))


def reach_of(points: np.ndarray, ee: np.ndarray) -> float:
    """The robot's reach, metres, over sampled configurations: the 90th percentile of the end-effector's
    distance from skeleton point 0 (its mean over the samples), at least 1 mm. points: (N, K, 3); ee: (N, 3)."""
    base = points[:, 0].mean(0)
    return max(float(np.percentile(np.linalg.norm(ee - base, axis=1), 90)), 1e-3)
