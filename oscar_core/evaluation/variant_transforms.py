"""Counterfactual variants of one trajectory: one decision changed, everything else held.

A variant is a list of transforms applied in order to a set's base :class:`~oscar_core.kinematics.trajectory.Trajectory`
(``oscar eval action-following``'s manifest, docs/action-following.md). Two kinds:

``{"gripper": "open" | "closed" | "flip", "from": t0, "to": t1}``
    every gripper's openness set to 1 (open), 0 (closed) or ``1 − openness`` (flip) on frames ``t0 <= t < t1``
    (``to`` omitted: to the end). Openness is the embodiment's (:meth:`Embodiment.gripper_openness`, 1 = open);
    the raw signals are written back through each gripper's ``signal_range``.

``{"shift_m": d, "axis": "x" | "y" | "z" | [ax, ay, az], "from": t0, "to": t1, "ramp": r}``
    the end-effector (the point the toy world and the skeleton renderer call it: :class:`~oscar_core.policy.ik.
    EndEffectorIK`) moved by ``d`` metres along the unit ``axis`` (world frame, the robot's base frame of the
    trajectory) on frames ``t0 <= t < t1``, blended in over the ``r`` frames before ``t0`` and out over the ``r``
    frames from ``t1`` with a minimum-jerk weight (0 at ``t0 − r``, 1 at ``t0``); every moved frame's arm joints are
    solved by damped least squares from the previous frame's solution (position only). Frame 0 never moves: the
    first frame is an image and must keep showing the arm where it is, so ``from`` must be at least 1 and a ramp
    that would start before frame 0 is cut to start there. A frame the arm cannot reach within
    :data:`SHIFT_TOLERANCE` of the shift is an error naming it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..kinematics.trajectory import Trajectory

__all__ = ["SHIFT_TOLERANCE", "VariantError", "apply_transforms", "check_transform", "shift_weights"]

#: A shifted frame's end-effector must lie within this fraction of |d| (at least 0.5 mm) of its target.
SHIFT_TOLERANCE = 0.02
_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


class VariantError(ValueError):
    """A transform that cannot be applied (bad field, or an arm that cannot follow the shift); names the field."""


def _frame(value, field: str, T: int, *, allow_end: bool = False) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise VariantError(f"field '{field}': expected a frame index (integer), found {value!r}")
    hi = T if allow_end else T - 1
    if not 0 <= int(value) <= hi:
        raise VariantError(f"field '{field}': expected a frame in [0, {hi}], found {value}")
    return int(value)


def _window(t: Mapping, T: int) -> tuple[int, int]:
    t0 = _frame(t.get("from", 0), "from", T)
    t1 = _frame(t.get("to", T), "to", T, allow_end=True)
    if t1 <= t0:
        raise VariantError(f"field 'to': expected a frame after 'from' ({t0}), found {t1}")
    return t0, t1


def check_transform(t, T: int) -> str:
    """The kind of transform ``t`` ("gripper" or "shift"), checked against a trajectory of ``T`` frames (fields and
    frame ranges; not yet whether the arm can follow a shift). Raises :class:`VariantError`."""
    if not isinstance(t, Mapping):
        raise VariantError(f"expected an object with 'gripper' or 'shift_m', found {type(t).__name__}")
    kinds = [k for k in ("gripper", "shift_m") if k in t]
    if len(kinds) != 1:
        raise VariantError(f"expected exactly one of 'gripper' and 'shift_m', found keys {sorted(t)}")
    if kinds[0] == "gripper":
        if t["gripper"] not in ("open", "closed", "flip"):
            raise VariantError(f"field 'gripper': expected 'open', 'closed' or 'flip', found {t['gripper']!r}")
        extra = sorted(set(t) - {"gripper", "from", "to"})
        if extra:
            raise VariantError(f"expected the fields gripper, from, to, found also {extra}")
        _window(t, T)
        return "gripper"
    d = t["shift_m"]
    if isinstance(d, bool) or not isinstance(d, (int, float)) or not np.isfinite(d) or d == 0:
        raise VariantError(f"field 'shift_m': expected a non-zero distance in metres, found {d!r}")
    _axis(t.get("axis"))
    extra = sorted(set(t) - {"shift_m", "axis", "from", "to", "ramp"})
    if extra:
        raise VariantError(f"expected the fields shift_m, axis, from, to, ramp, found also {extra}")
    t0, _ = _window(t, T)
    if t0 < 1:
        raise VariantError("field 'from': expected a frame >= 1 (frame 0 is the first frame's image), found 0")
    r = t.get("ramp", 0)
    if isinstance(r, bool) or not isinstance(r, (int, np.integer)) or r < 0:
        raise VariantError(f"field 'ramp': expected a frame count >= 0, found {r!r}")
    return "shift"


def _axis(axis) -> np.ndarray:
    if isinstance(axis, str) and axis in _AXES:
        return np.array(_AXES[axis])
    a = np.asarray(axis, dtype=np.float64) if isinstance(axis, (list, tuple)) else None
    if a is None or a.shape != (3,) or not np.isfinite(a).all() or np.linalg.norm(a) == 0:
        raise VariantError(f"field 'axis': expected 'x', 'y', 'z' or a non-zero [x, y, z], found {axis!r}")
    return a / np.linalg.norm(a)


def _smooth(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk blend 10s³ − 15s⁴ + 6s⁵ of s in [0, 1]."""
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s * s)


def shift_weights(T: int, start: int, stop: int, ramp: int) -> np.ndarray:
    """(T,) weight of a shift on each frame: 1 on ``start <= t < stop``, a minimum-jerk blend over the ``ramp`` frames
    on each side (0 at ``start − ramp`` and at ``stop − 1 + ramp``), 0 elsewhere; frame 0 always 0."""
    t = np.arange(T, dtype=np.float64)
    w = np.zeros(T)
    w[start:stop] = 1.0
    if ramp > 0:
        lo = max(start - ramp, 0)
        if start > lo:
            idx = np.arange(lo, start)
            w[idx] = _smooth((t[idx] - lo) / (start - lo))
        idx = np.arange(stop, min(stop + ramp, T))
        w[idx] = _smooth(1.0 - (t[idx] - (stop - 1)) / ramp)
    w[0] = 0.0
    return w


def _gripper(traj: Trajectory, emb, t: Mapping) -> Trajectory:
    from ..kinematics.workspace import openness_to_signal

    T = len(traj.q)
    t0, t1 = _window(t, T)
    if not len(emb.grippers):
        raise VariantError(f"field 'gripper': embodiment {emb.name!r} has no gripper")
    o = emb.gripper_openness(traj.gripper, traj.source).copy()
    o[t0:t1] = {"open": 1.0, "closed": 0.0}[t["gripper"]] if t["gripper"] != "flip" else 1.0 - o[t0:t1]
    return _replace(traj, gripper=openness_to_signal(emb, o))


def _shift(traj: Trajectory, emb, t: Mapping, ik) -> Trajectory:
    from ..policy.ik import EndEffectorIK

    T = len(traj.q)
    t0, t1 = _window(t, T)
    d = float(t["shift_m"]) * _axis(t.get("axis"))
    w = shift_weights(T, t0, t1, int(t.get("ramp", 0)))
    ik = ik or EndEffectorIK(emb)
    q = traj.q.copy()
    ee = ik.pose(traj.q)[:, :3, 3]
    tol = max(SHIFT_TOLERANCE * float(np.linalg.norm(d)), 5e-4)
    prev = q[0]
    for k in range(1, T):
        if w[k] == 0.0:
            prev = q[k]
            continue
        res = ik.solve(prev if w[k - 1] > 0 else q[k], ee[k] + w[k] * d)
        if res.position_error > tol:
            raise VariantError(
                f"field 'shift_m': expected an arm that can follow the shift, found frame {k} "
                f"{res.position_error * 1000:.1f} mm from its target (tolerance {tol * 1000:.1f} mm)"
            )
        q[k] = prev = res.q
    return _replace(traj, q=q)


def _replace(traj: Trajectory, **changes) -> Trajectory:
    import dataclasses

    return dataclasses.replace(traj, **changes)


def apply_transforms(traj: Trajectory, emb, transforms: Sequence[Mapping], ik=None) -> Trajectory:
    """``traj`` with ``transforms`` applied in order (module docstring); ``emb``: its embodiment; ``ik``: an
    :class:`~oscar_core.policy.ik.EndEffectorIK` to reuse (default: one made for ``emb``). Raises
    :class:`VariantError` naming the transform's index and field."""
    T = len(traj.q)
    for i, t in enumerate(transforms):
        try:
            kind = check_transform(t, T)
            traj = _gripper(traj, emb, t) if kind == "gripper" else _shift(traj, emb, t, ik)
        except VariantError as exc:
            raise VariantError(f"transforms[{i}]: {exc}") from None
    return traj
