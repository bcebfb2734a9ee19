"""Reading a camera file's fields: numbers, vectors, matrices, and the ``extrinsic`` in its three forms,
static or per frame (the file format is in :mod:`oscar_core.camera.file`'s docstring). Errors are
:class:`~oscar_core.errors.CameraFileError` naming the file, the field, what was expected and found.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from oscar_core.errors import CameraFileError

from .geometry import ORTHONORMAL_TOL, is_number, rigid_problem, rotation_from_quat_xyzw, rotation_from_rpy

__all__ = []

# --------------------------------------------------------------------------- file parsing

_EXTRINSIC_FORMS = ("matrix", "xyz_rpy", "xyz_quat_xyzw")


def short_repr(x: Any, limit: int = 120) -> str:
    s = json.dumps(x) if isinstance(x, (dict, list, str, int, float, bool, type(None))) else repr(x)
    return s if len(s) <= limit else s[: limit - 3] + "..."


def read_number(src: str, fieldname: str, v: Any) -> float:
    if not is_number(v) or not math.isfinite(v):
        raise CameraFileError(src, fieldname, "a finite number", short_repr(v))
    return float(v)


def read_vector(src: str, fieldname: str, v: Any, n: int, what: str) -> list[float]:
    if not isinstance(v, (list, tuple)) or len(v) != n:
        found = f"a list of length {len(v)}" if isinstance(v, (list, tuple)) else short_repr(v)
        raise CameraFileError(src, fieldname, f"a list of {n} numbers {what}", found)
    return [read_number(src, f"{fieldname}[{k}]", x) for k, x in enumerate(v)]


def read_matrix(src: str, fieldname: str, v: Any, rows: int, cols: int) -> np.ndarray:
    ok = (
        isinstance(v, (list, tuple))
        and len(v) == rows
        and all(isinstance(r, (list, tuple)) and len(r) == cols for r in v)
    )
    if not ok:
        try:
            found = f"shape {np.asarray(v, dtype=object).shape}"
        except Exception:  # noqa: BLE001 (numpy refuses ragged nesting in several ways; only a shape is wanted)
            found = short_repr(v)
        raise CameraFileError(src, fieldname, f"a {rows}x{cols} nested list of numbers", found)
    return np.array(
        [[read_number(src, f"{fieldname}[{r}][{c}]", x) for c, x in enumerate(row)] for r, row in enumerate(v)]
    )


def _per_frame(form: str, value: Any) -> bool:
    """True when ``value`` nests one level deeper than one extrinsic of ``form``."""
    depth = 3 if form == "matrix" else 2
    node = value
    for _ in range(depth):
        if not isinstance(node, (list, tuple)) or not node:
            return False
        node = node[0]
    return True


def read_extrinsic(v: Any, src: str) -> np.ndarray:
    """(4, 4), or (T, 4, 4) when the form holds one value per frame."""
    if not isinstance(v, Mapping) or len(v) != 1 or next(iter(v)) not in _EXTRINSIC_FORMS:
        found = f"keys {sorted(v)}" if isinstance(v, Mapping) else short_repr(v)
        raise CameraFileError(
            src, "extrinsic", f"an object with exactly one of the keys {list(_EXTRINSIC_FORMS)}", found
        )
    form, value = next(iter(v.items()))
    if _per_frame(form, value):
        fast = _per_frame_fast(form, value)
        if fast is not None:
            return fast
        # slow path: one frame at a time, so that an error names the frame and the entry
        return np.stack(
            [_parse_one_extrinsic(form, item, f"extrinsic.{form}[{t}]", src) for t, item in enumerate(value)]
        )
    return _parse_one_extrinsic(form, value, f"extrinsic.{form}", src)


def _per_frame_fast(form: str, value: Any) -> np.ndarray | None:
    """(T, 4, 4) from a well-formed per-frame list in one numpy pass, or None (then the
    frame-by-frame parser finds and names the problem)."""
    width = {"matrix": None, "xyz_rpy": 6, "xyz_quat_xyzw": 7}[form]
    try:
        A = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if A.dtype != np.float64 or not np.isfinite(A).all():
        return None
    if any(isinstance(x, bool) for x in np.asarray(value, dtype=object).reshape(-1)):
        return None
    if form == "matrix":
        if A.ndim != 3 or A.shape[1:] != (4, 4):
            return None
        R = A[:, :3, :3]
        dev = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(1, 2))
        ok = (
            (np.abs(A[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) <= 1e-12)
            & (dev <= ORTHONORMAL_TOL)
            & (np.linalg.det(R) >= 0)
        )
        return A if ok.all() else None
    if A.ndim != 2 or A.shape[1] != width:
        return None
    M = np.tile(np.eye(4), (len(A), 1, 1))
    M[:, :3, 3] = A[:, :3]
    if form == "xyz_rpy":
        r, p, y = A[:, 3], A[:, 4], A[:, 5]
        cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
        M[:, :3, :3] = np.stack(
            [
                np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
                np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
                np.stack([-sp, cp * sr, cp * cr], -1),
            ],
            axis=1,
        )
    else:
        q = A[:, 3:]
        n = np.linalg.norm(q, axis=1)
        if (np.abs(n - 1.0) > 1e-3).any():
            return None
        x, y, z, w = (q / n[:, None]).T
        M[:, :3, :3] = np.stack(
            [
                np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
            ],
            axis=1,
        )
    return M


def _parse_one_extrinsic(form: str, value: Any, fname: str, src: str) -> np.ndarray:
    if form == "matrix":
        M = read_matrix(src, fname, value, 4, 4)
        problem = rigid_problem(M)
        if problem is not None:
            raise CameraFileError(src, fname, *problem)
        return M
    M = np.eye(4)
    if form == "xyz_rpy":
        x, y, z, roll, pitch, yaw = read_vector(src, fname, value, 6, "[x, y, z, roll, pitch, yaw] (metres, radians)")
        M[:3, :3] = rotation_from_rpy(roll, pitch, yaw)
    else:
        x, y, z, qx, qy, qz, qw = read_vector(src, fname, value, 7, "[x, y, z, qx, qy, qz, qw] (metres)")
        n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
        if abs(n - 1.0) > 1e-3:
            raise CameraFileError(src, fname, "a unit quaternion (norm within 1e-3 of 1)", f"norm {n:.6g}")
        M[:3, :3] = rotation_from_quat_xyzw(qx / n, qy / n, qz / n, qw / n)
    M[:3, 3] = (x, y, z)
    return M
