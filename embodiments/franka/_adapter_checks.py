"""The checks the Franka dataset adapters (:mod:`oscar_embodiments.franka.adapters`) share: field lookup in flat,
nested or h5py records, numeric arrays (finite), joint angles (radians, (T, 7)), per-frame columns, value ranges,
rotations (X-Y-Z Euler angles, unit quaternions w-x-y-z), rigid and static extrinsics (metres), intrinsics
(pixels) and frame rates from timestamps (ms or s). Each raises :class:`oscar_core.TrajectoryError` /
:class:`oscar_core.CameraFileError` naming the field, what was expected and what was found.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from oscar_core.camera import Intrinsics, as_rigid_transform
from oscar_core.errors import CameraFileError, TrajectoryError

__all__ = ["ORTHO_TOL", "STATIC_TOL"]

STATIC_TOL = 1e-4  # m / rad: how much a "static" extrinsic may vary over an episode
ORTHO_TOL = 1e-3  # rotation blocks stored in float32 are re-orthonormalised below this error


def _lookup(record: Any, keys: tuple[str, ...], source: str, what: str, error=TrajectoryError):
    """The first of ``keys`` present in ``record`` (flat "a/b/c" keys, nested mappings or h5py groups)."""
    for key in keys:
        try:
            return record[key]
        except (KeyError, TypeError, ValueError):
            pass
        node = record
        try:
            for part in key.split("/"):
                node = node[part]
            return node
        except (KeyError, TypeError, ValueError, IndexError):
            continue
    raise error(source, keys[0], f"{what} (looked for {', '.join(repr(k) for k in keys)})", "missing")


def _array(value: Any, source: str, field: str, what: str, error=TrajectoryError) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)  # arrays, lists, h5py datasets, torch tensors, pandas columns
    except (TypeError, ValueError):
        try:  # a column whose cells are arrays (pandas / pyarrow list columns)
            a = np.stack([np.asarray(v, dtype=np.float64) for v in value])
        except (TypeError, ValueError):
            raise error(source, field, what, f"non-numeric data of type {type(value).__name__}") from None
    if not np.isfinite(a).all():
        raise error(source, field, f"{what}, finite values", f"{int((~np.isfinite(a)).sum())} non-finite values")
    return a


def _joints(value: Any, source: str, field: str, frames_of: str = "T") -> np.ndarray:
    q = _array(value, source, field, "joint positions, radians, shape (T, 7)")
    if q.ndim != 2 or q.shape[1] < 7:
        raise TrajectoryError(source, field, f"shape ({frames_of}, 7): panda_joint1..7 in radians", f"shape {q.shape}")
    return _radians(q[:, :7], source, field)


def _radians(q: np.ndarray, source: str, field: str) -> np.ndarray:
    """Refuse joint angles that cannot be radians (|q| > 2 pi): most likely degrees."""
    if np.abs(q).max() > 2 * np.pi:
        t, j = np.unravel_index(int(np.argmax(np.abs(q))), q.shape)
        raise TrajectoryError(
            source,
            field,
            "joint angles in radians (|q| <= 2 pi)",
            f"{q[t, j]:g} at frame {t}, joint {j + 1} (degrees?)",
        )
    return q


def _column(value: Any, source: str, field: str, T: int, what: str) -> np.ndarray:
    g = _array(value, source, field, what)
    if g.ndim == 2 and g.shape[1] == 1:
        g = g[:, 0]
    if g.shape != (T,):
        raise TrajectoryError(
            source, field, f"{what}, shape ({T},) or ({T}, 1) (one value per frame)", f"shape {g.shape}"
        )
    return g


def _check_range(
    values: np.ndarray, lo: float, hi: float, source: str, field: str, what: str, tolerance: float = 0.05
) -> np.ndarray:
    """Values in [lo, hi] ± tolerance × span, clipped; else an error naming the first bad frame."""
    slack = tolerance * (hi - lo)
    bad = np.flatnonzero((values < lo - slack) | (values > hi + slack))
    if bad.size:
        t = int(bad[0])
        raise TrajectoryError(
            source, field, f"{what} in [{lo:g}, {hi:g}]", f"{values[t]:g} at frame {t} ({bad.size} frames out of range)"
        )
    return np.clip(values, lo, hi)


def _rotation_xyz(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Fixed-axis X-Y-Z Euler angles: R = Rz(yaw) @ Ry(pitch) @ Rx(roll) (scipy ``"xyz"``)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _rotation_quat_wxyz(w: float, x: float, y: float, z: float) -> np.ndarray:
    n = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _rigid(M: np.ndarray, source: str, field: str) -> np.ndarray:
    """A 4×4 rigid transform, its rotation re-orthonormalised if stored in low precision."""
    return as_rigid_transform(M, source, field, tol=ORTHO_TOL)


def _static(per_frame: np.ndarray, source: str, field: str, hint: str) -> np.ndarray:
    """First row of a per-frame calibration, after checking the others equal it (a static camera)."""
    if per_frame.ndim >= 2 and per_frame.shape[0] > 1:
        spread = float(np.abs(per_frame - per_frame[:1]).max())
        if spread > STATIC_TOL:
            t = int(np.argmax(np.abs(per_frame - per_frame[:1]).reshape(len(per_frame), -1).max(axis=1)))
            raise CameraFileError(
                source,
                field,
                f"a static camera: the same extrinsic in every frame ({hint})",
                f"a change of {spread:.3g} at frame {t}",
            )
    return per_frame[0] if per_frame.ndim >= 2 else per_frame


def _intrinsics(K: Any, image_size: tuple[int, int], source: str, field: str) -> Intrinsics:
    """Intrinsics from a 3x3 / 3x4 camera matrix or (fx, fy, cx, cy)."""
    K = _array(K, source, field, "a 3x3 camera matrix or (fx, fy, cx, cy), pixels", error=CameraFileError)
    if K.shape == (4,):
        fx, fy, cx, cy = K
    elif K.shape in ((3, 3), (3, 4)):
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    else:
        raise CameraFileError(
            source, field, "a 3x3 (or 3x4) camera matrix or (fx, fy, cx, cy), pixels", f"shape {K.shape}"
        )
    try:
        return Intrinsics(float(fx), float(fy), float(cx), float(cy), int(image_size[0]), int(image_size[1]))
    except CameraFileError as e:
        raise CameraFileError(source, f"{field}.{e.field}", e.expected, e.found) from None


def _timestamps_ms(keys, source: str, field: str) -> np.ndarray:
    try:
        ts = np.array(sorted(int(k) for k in keys), dtype=np.int64)
    except (TypeError, ValueError):
        raise TrajectoryError(
            source, field, "integer timestamps in milliseconds as keys", f"keys {list(keys)[:3]}..."
        ) from None
    if ts.size == 0:
        raise TrajectoryError(source, field, "at least one timestamped frame", "none")
    return ts


def _fps_from(ts_s: np.ndarray, fps: float | None, source: str, field: str) -> float:
    if fps is not None:
        return float(fps)
    if ts_s.size < 2:
        raise TrajectoryError(
            source, field, "two or more frames to infer the frame rate (or pass fps=)", f"{ts_s.size} frame"
        )
    dt = np.diff(ts_s)
    if (dt <= 0).any():
        raise TrajectoryError(source, field, "strictly increasing timestamps", f"a step of {dt.min():g} s")
    return float(1.0 / np.median(dt))
