"""Action-space adapters: a policy's action rows → joint positions and gripper closure at its control rate,
and the resampling of that path to a world model's frame rate.

Every action space holds the arm part and one gripper column (last). Starting from joint positions q₀ (J,),
action i (0-based) gives the joint positions q_{i+1} reached at time (i + 1) / control_hz seconds:

============================ ================ =========================================================
space                        arm columns      q_{i+1}
============================ ================ =========================================================
``joint_position``           J (rad / m)      a_i
``joint_velocity``           J (rad/s, m/s)   q_i + a_i / control_hz (each velocity held for one period)
``joint_delta``              J                q_i + a_i
``ee_pose``                  6: xyz, rotvec   IK of the end-effector pose (metres; axis × angle, radians)
``ee_delta``                 6: dxyz, drotvec IK of (p_i + dxyz, Rot(drotvec) · R_i), p_i, R_i the pose at q_i
``ee_position``              3: xyz           IK of the end-effector position only
``ee_position_delta``        3: dxyz          IK of p_i + dxyz
============================ ================ =========================================================

End-effector spaces are in the robot's base (world) frame and go through
:class:`~oscar_core.policy.ik.EndEffectorIK` seeded with q_i; the IK residual (metres, radians) is kept per
action. Every q_{i+1} is then clipped to the joint limits (``joint_limits(emb, shrink=0)``); an action whose
joint values were clipped counts once in ``clipped`` (for velocity and delta spaces the clipped position is
what the next action starts from, as on a robot that stops at its limit).

The gripper column is the closure in [0, 1] (1 = closed, DROID's ``gripper_position``): ``position`` takes it
clipped to [0, 1] (a clip is counted), ``binary`` thresholds it at 0.5.

:func:`resample` turns the path (knots at the control rate) into frames at the model's rate: joints linearly
between knots, the gripper held at its latest knot. :func:`resample_joints` puts a recorded episode (every
column continuous, timestamps possibly uneven) on a uniform frame grid; both read the knots with the same
per-column linear interpolation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..kinematics.workspace import joint_limits
from .protocol import ACTION_SPACES, GRIPPER_MODES, absurd_bounds, action_width

__all__ = ["AdapterResult", "ActionAdapter", "resample", "resample_joints"]


@dataclass
class AdapterResult:
    """What K actions did. q: (K, J) joint positions at the end of each action; closure: (K,) gripper closure
    in [0, 1]; clipped: actions with a joint value (or gripper value) clipped; ik_position_error,
    ik_rotation_error: (K,) metres / radians (NaN for joint spaces)."""

    q: np.ndarray
    closure: np.ndarray
    clipped: int
    ik_position_error: np.ndarray
    ik_rotation_error: np.ndarray


class ActionAdapter:
    """Turns action rows of one declared space into joint positions (module docstring).

    emb: the embodiment; space: :data:`~oscar_core.policy.protocol.ACTION_SPACES`; gripper:
    :data:`~oscar_core.policy.protocol.GRIPPER_MODES`; control_hz: actions per second.
    """

    def __init__(self, emb, space: str, gripper: str = "position", control_hz: float = 15.0):
        if space not in ACTION_SPACES:
            raise ValueError(f"action_space: expected one of {list(ACTION_SPACES)}, found {space!r}")
        if gripper not in GRIPPER_MODES:
            raise ValueError(f"gripper: expected one of {list(GRIPPER_MODES)}, found {gripper!r}")
        self.emb, self.space, self.gripper, self.hz = emb, space, gripper, float(control_hz)
        self.lo, self.hi = joint_limits(emb, shrink=0.0)
        self.joints = len(self.lo)
        self.width = action_width(space, self.joints)
        self._ik = None

    @property
    def ik(self):
        if self._ik is None:
            from .ik import EndEffectorIK

            self._ik = EndEffectorIK(self.emb)
        return self._ik

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(D,) bounds past which an action is absurd (:func:`~oscar_core.policy.protocol.absurd_bounds`)."""
        return absurd_bounds(self.space, self.lo, self.hi, self.hz)

    def apply(self, actions, q0) -> AdapterResult:
        """Execute ``actions`` (K, D) from joint positions ``q0`` (J,)."""
        a = np.asarray(actions, dtype=np.float64)
        if a.ndim != 2 or a.shape[1] != self.width:
            raise ValueError(f"actions: expected shape (K, {self.width}) for {self.space}, found {a.shape}")
        K = len(a)
        q = np.asarray(q0, dtype=np.float64).copy()
        out = np.empty((K, self.joints))
        ep, er = np.full(K, np.nan), np.full(K, np.nan)
        clipped = np.zeros(K, dtype=bool)
        for i, row in enumerate(a):
            arm = row[:-1]
            if self.space == "joint_position":
                nxt = arm
            elif self.space == "joint_velocity":
                nxt = q + arm / self.hz
            elif self.space == "joint_delta":
                nxt = q + arm
            else:
                if self.space in ("ee_delta", "ee_position_delta"):
                    T = self.ik.pose(q)
                    pos = T[:3, 3] + arm[:3]
                    rot = (
                        (Rotation.from_rotvec(arm[3:6]) * Rotation.from_matrix(T[:3, :3])).as_rotvec()
                        if self.space == "ee_delta"
                        else None
                    )
                else:
                    pos, rot = arm[:3], (arm[3:6] if self.space == "ee_pose" else None)
                res = self.ik.solve(q, pos, rot)
                nxt, ep[i], er[i] = res.q, res.position_error, res.rotation_error
            lim = np.clip(nxt, self.lo, self.hi)
            clipped[i] = bool(np.any(lim != nxt))
            q = lim
            out[i] = q
        g = a[:, -1]
        if self.gripper == "binary":
            closure = (g >= 0.5).astype(np.float64)
        else:
            closure = np.clip(g, 0.0, 1.0)
            clipped |= closure != g
        return AdapterResult(out, closure, int(clipped.sum()), ep, er)


def _interpolate_columns(times: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """(N, D) values of each column of ``values`` (M, D), known at increasing ``times`` (M,) seconds, read at
    ``at`` (N,) seconds: linear between knots, the nearest knot's value outside them."""
    if values.shape[1] == 0:
        return np.zeros((len(at), 0))
    return np.stack([np.interp(at, times, values[:, j]) for j in range(values.shape[1])], axis=1)


def resample(times: np.ndarray, q: np.ndarray, closure: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Joint positions and gripper closure at times ``at`` (N,) seconds from knots ``times`` (M,) increasing,
    ``q`` (M, J), ``closure`` (M,): joints linear between knots, the gripper held at the latest knot at or before
    each time; times outside the knots take the nearest knot's values. Returns (N, J) and (N,)."""
    times, at = np.asarray(times, float), np.asarray(at, float)
    qs = _interpolate_columns(times, np.asarray(q, float), at)
    idx = np.clip(np.searchsorted(times, at + 1e-9, side="right") - 1, 0, len(times) - 1)
    return qs, np.asarray(closure, float)[idx]


def resample_joints(values: np.ndarray, times: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Resample (T, D) ``values`` known at increasing ``times`` (T,) seconds to a uniform ``fps`` grid.

    The grid starts at ``times[0]`` and holds every ``times[0] + k / fps`` up to ``times[-1]`` (floor, with
    1e-9 s of slack); each column is linear between its knots. Returns ((N, D) values, (N,) times).
    """
    values = np.asarray(values, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    if values.ndim != 2 or len(values) != len(times) or len(times) < 1:
        raise ValueError(f"resample_joints: expected (T, D) values with T = len(times), found {values.shape}")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"resample_joints: expected fps > 0, found {fps!r}")
    if len(times) > 1 and not np.all(np.diff(times) > 0):
        raise ValueError("resample_joints: expected strictly increasing times")
    n = int(np.floor((times[-1] - times[0]) * fps + 1e-9)) + 1
    at = times[0] + np.arange(n) / fps
    return _interpolate_columns(times, values, at), at
