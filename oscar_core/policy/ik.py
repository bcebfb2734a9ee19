"""Inverse kinematics by damped least squares on the project's own forward kinematics.

The end-effector frame of an embodiment is its first gripper's link (else its first ``end_effector_links``
entry, else the last skeleton link) moved by the gripper's indicator offset: the point the toy world and the
skeleton renderer call the end-effector. :class:`EndEffectorIK` computes its pose with
:class:`~oscar_core.kinematics.fk_numpy.NumpyForwardKinematics` and solves for the arm joints that reach a
target position (and, optionally, rotation) with damped least squares (Levenberg–Marquardt's damping; the
Jacobian by central differences of the FK, all 2J configurations in one FK call), clipping to the joint limits
after every step. Units: metres, radians; rotations as rotation vectors (axis × angle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..kinematics.fk_numpy import NumpyForwardKinematics
from ..kinematics.workspace import joint_limits

__all__ = ["EndEffectorIK", "IKResult"]


@dataclass
class IKResult:
    """q: (J,) radians / metres; position_error: metres; rotation_error: radians (0 for position-only targets);
    iterations: steps taken."""

    q: np.ndarray
    position_error: float
    rotation_error: float
    iterations: int


class EndEffectorIK:
    """Forward and inverse kinematics of one embodiment's end-effector frame (module docstring).

    damping: λ of ``dq = Jᵀ (J Jᵀ + λ² I)⁻¹ e`` (metres); max_iter: steps per solve; tol_m / tol_rad: the
    position and rotation errors at which a solve stops.
    """

    def __init__(
        self,
        emb,
        damping: float = 0.02,
        max_iter: int = 200,
        tol_m: float = 1e-5,
        tol_rad: float = 1e-4,
        eps: float = 1e-6,
    ):
        self.emb = emb
        self.fk = NumpyForwardKinematics(emb.tree)
        if len(emb.grippers):
            self.link, self.offset = emb.grippers[0].link, np.asarray(emb.grippers[0].point, float)
        elif emb.end_effector_links:
            self.link, self.offset = emb.end_effector_links[0], np.zeros(3)
        else:
            self.link, self.offset = emb.skeleton.links[-1], np.zeros(3)
        names = emb.joint_names
        self.arm = [emb.tree.joint_names.index(n) for n in names]
        self.lo, self.hi = joint_limits(emb, shrink=0.0)
        self.damping, self.max_iter, self.tol_m, self.tol_rad, self.eps = damping, max_iter, tol_m, tol_rad, eps

    def _full(self, q: np.ndarray) -> np.ndarray:
        """(N, J) arm joints → (N, J_tree), other joints (fingers) at 0."""
        full = np.zeros((q.shape[0], len(self.emb.tree.joint_names)))
        full[:, self.arm] = q
        return full

    def pose(self, q) -> np.ndarray:
        """(4, 4) end-effector pose for arm joints q (J,), or (N, 4, 4) for (N, J)."""
        q = np.asarray(q, dtype=np.float64)
        flat = q.reshape(-1, q.shape[-1])
        T = self.fk(self._full(flat), [self.link])[:, 0].copy()
        T[:, :3, 3] = T[:, :3, 3] + T[:, :3, :3] @ self.offset
        return T[0] if q.ndim == 1 else T

    def solve(self, q0, position, rotvec=None, restarts: int = 4) -> IKResult:
        """Arm joints near ``q0`` (J,) that put the end-effector at ``position`` (3,) metres (and rotation
        ``rotvec`` (3,) if given), within the joint limits; the residual is whatever is left after the solve.

        A solve from ``q0`` that ends more than 1 mm (or 1 mrad) away — a local minimum against the limits —
        is repeated from ``restarts`` fixed configurations (a generator of seed 0, uniform in the limits) and
        the one with the smallest residual is kept (the arm may then jump in joint space)."""
        best = self._solve(q0, position, rotvec)
        if best.position_error <= 1e-3 and best.rotation_error <= 1e-3:
            return best
        rng = np.random.default_rng(0)
        for _ in range(restarts):
            res = self._solve(self.lo + rng.uniform(0, 1, len(self.lo)) * (self.hi - self.lo), position, rotvec)
            if res.position_error + res.rotation_error < best.position_error + best.rotation_error:
                best = res
            if best.position_error <= 1e-3 and best.rotation_error <= 1e-3:
                break
        return best

    def _solve(self, q0, position, rotvec=None) -> IKResult:
        q = np.clip(np.asarray(q0, dtype=np.float64).copy(), self.lo, self.hi)
        target_p = np.asarray(position, dtype=np.float64)
        target_R = Rotation.from_rotvec(rotvec).as_matrix() if rotvec is not None else None
        rows = 6 if target_R is not None else 3
        J = len(q)
        eye = np.eye(rows)
        ep, er = np.inf, 0.0
        it = 0
        for it in range(self.max_iter + 1):
            probes = np.concatenate([q[None], q + self.eps * np.eye(J), q - self.eps * np.eye(J)])
            T = self.pose(probes)
            err = self._error(T[0], target_p, target_R)
            ep = float(np.linalg.norm(err[:3]))
            er = float(np.linalg.norm(err[3:])) if rows == 6 else 0.0
            if (ep <= self.tol_m and er <= self.tol_rad) or it == self.max_iter:
                break
            plus, minus = T[1 : J + 1], T[J + 1 :]
            jac = np.empty((rows, J))
            jac[:3] = ((plus[:, :3, 3] - minus[:, :3, 3]) / (2 * self.eps)).T
            if rows == 6:  # rotation rows: rotvec of R+ R-ᵀ / 2ε (the angular velocity per unit joint motion)
                rel = np.einsum("nij,nkj->nik", plus[:, :3, :3], minus[:, :3, :3])
                jac[3:] = (Rotation.from_matrix(rel).as_rotvec() / (2 * self.eps)).T
            dq = jac.T @ np.linalg.solve(jac @ jac.T + self.damping**2 * eye, err)
            q = np.clip(q + dq, self.lo, self.hi)
        return IKResult(q, ep, er, it)

    @staticmethod
    def _error(T: np.ndarray, p: np.ndarray, R: np.ndarray | None) -> np.ndarray:
        e = p - T[:3, 3]
        if R is None:
            return e
        return np.concatenate([e, Rotation.from_matrix(R @ T[:3, :3].T).as_rotvec()])
