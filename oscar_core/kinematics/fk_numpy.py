"""Forward kinematics of a :class:`~oscar_core.kinematics.urdf.KinematicTree` in NumPy (float64).

The renderer's CPU path: no torch and no pytorch-kinematics import (which
costs seconds at start-up and pulls in matplotlib), and each frame's poses
are computed on their own, so a frame's result never depends on how many
frames are evaluated together. :class:`oscar_core.kinematics.fk_torch.ForwardKinematics`
(torch) stays the path for GPUs and for plugins that override ``fk``; the two
agree to ~1e-12 m (tests/render/test_render_stream.py).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .urdf import Joint, KinematicTree

__all__ = ["NumpyForwardKinematics"]


def _motion(joint: Joint, value: np.ndarray) -> np.ndarray:
    """(T, 4, 4) motion of ``joint`` at ``value`` (T,) radians or metres, in the child frame."""
    T = value.shape[0]
    M = np.zeros((T, 4, 4))
    M[:, 3, 3] = 1.0
    a = joint.axis
    if joint.type in ("revolute", "continuous"):
        c, s = np.cos(value), np.sin(value)
        C = 1.0 - c
        x, y, z = (float(v) for v in a)
        M[:, 0, 0] = c + x * x * C
        M[:, 0, 1] = x * y * C - z * s
        M[:, 0, 2] = x * z * C + y * s
        M[:, 1, 0] = y * x * C + z * s
        M[:, 1, 1] = c + y * y * C
        M[:, 1, 2] = y * z * C - x * s
        M[:, 2, 0] = z * x * C - y * s
        M[:, 2, 1] = z * y * C + x * s
        M[:, 2, 2] = c + z * z * C
    elif joint.type == "prismatic":
        M[:, 0, 0] = M[:, 1, 1] = M[:, 2, 2] = 1.0
        M[:, :3, 3] = value[:, None] * a
    else:  # fixed
        M[:, 0, 0] = M[:, 1, 1] = M[:, 2, 2] = 1.0
    return M


class NumpyForwardKinematics:
    """``q (T, J)`` in ``tree.joint_names`` order → link poses ``(T, K, 4, 4)`` float64.

    Mimic joints follow their source joint (``multiplier * q + offset``).
    Poses are in the root-link frame, or in the world when ``base_pose`` is given.
    """

    def __init__(self, tree: KinematicTree):
        self.tree = tree
        self._index = {n: i for i, n in enumerate(tree.joint_names)}
        self._paths: dict[str, tuple[Joint, ...]] = {}

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.tree.joint_names

    def _path(self, link: str) -> tuple[Joint, ...]:
        """Joints from the root down to ``link``."""
        if link not in self._paths:
            if link != self.tree.root and link not in self.tree.joint_of:
                raise KeyError(f"{self.tree.source}: unknown link {link!r}; links: {', '.join(self.tree.links)}")
            chain = []
            cur = link
            while cur in self.tree.joint_of:
                j = self.tree.joint_of[cur]
                chain.append(j)
                cur = j.parent
            self._paths[link] = tuple(reversed(chain))
        return self._paths[link]

    def _value(self, joint: Joint, q: np.ndarray) -> np.ndarray:
        if joint.mimic is not None:
            src, mult, off = joint.mimic
            return mult * q[:, self._index[src]] + off
        return q[:, self._index[joint.name]]

    def __call__(self, q, links: Sequence[str], base_pose=None) -> np.ndarray:
        """Poses of ``links``: q (T, J) radians / metres → (T, K, 4, 4) float64.

        base_pose: optional (4, 4) or (T, 4, 4) world pose of the root link.
        """
        q = np.asarray(q, dtype=np.float64)
        J = len(self.joint_names)
        if q.ndim != 2 or q.shape[1] != J:
            raise ValueError(f"q: expected shape (T, {J}), found {q.shape}")
        T = q.shape[0]
        poses: dict[str, np.ndarray] = {}
        identity = np.broadcast_to(np.eye(4), (T, 4, 4))
        out = np.empty((T, len(links), 4, 4))
        for k, link in enumerate(links):
            pose = identity
            for j in self._path(link):
                if j.child in poses:
                    pose = poses[j.child]
                    continue
                pose = pose @ j.origin
                if j.type != "fixed":
                    pose = pose @ _motion(j, self._value(j, q))
                poses[j.child] = pose
            out[:, k] = pose
        if base_pose is not None:
            base = np.asarray(base_pose, dtype=np.float64)
            if base.shape not in ((4, 4), (T, 4, 4)):
                raise ValueError(f"base_pose: expected shape (4, 4) or ({T}, 4, 4), found {base.shape}")
            out = (base[:, None] if base.ndim == 3 else base) @ out
        return out
