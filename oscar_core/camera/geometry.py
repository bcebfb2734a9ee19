"""Camera-frame conventions and rigid transforms: the geometry every camera file and projection uses.

Units: metres and radians. Conventions (``CONVENTIONS``) and the meaning of ``direction`` are in
:mod:`oscar_core.camera.pinhole`'s docstring (the camera file: :mod:`oscar_core.camera.file`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import numpy as np

from oscar_core.errors import CameraFileError

__all__ = [
    "CONVENTIONS",
    "CONVENTION_ALIASES",
    "DIRECTIONS",
    "canonical_convention",
    "convention_to_opencv",
    "as_rigid_transform",
    "as_rigid_transforms",
    "look_at",
    "rotation_from_rpy",
    "rotation_from_quat_xyzw",
]

# --------------------------------------------------------------------------- conventions

#: Canonical convention name -> meaning of the camera-frame axes.
CONVENTIONS: Mapping[str, str] = MappingProxyType(
    {
        "opencv": "x right, y down, z forward (looking direction)",
        "opengl": "x right, y up, z backward (camera looks along -z)",
        "ros_body": "x forward, y left, z up (ROS REP-103 camera_link body frame)",
    }
)

#: Alias -> canonical convention name.
CONVENTION_ALIASES: Mapping[str, str] = MappingProxyType(
    {"ros_optical": "opencv", "blender": "opengl", "ros": "ros_body"}
)

DIRECTIONS: tuple[str, ...] = ("camera_to_world", "world_to_camera")

# Rotation part of T_cvcam_conv: p_cv = R @ p_conv.
_CONV_TO_CV_ROT = {
    "opencv": np.eye(3),
    "opengl": np.diag([1.0, -1.0, -1.0]),
    # cv x (right) = -y_ros (left), cv y (down) = -z_ros (up), cv z (forward) = x_ros
    "ros_body": np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]),
}

CONVENTION_NAMES = tuple(CONVENTIONS) + tuple(CONVENTION_ALIASES)
DISTORTION_LENGTHS = (0, 4, 5, 8, 12)
ORTHONORMAL_TOL = 1e-4  # float32-stored calibrations (RH20T, InternData) deviate by ~1e-5


def canonical_convention(name: str) -> str:
    """Return the canonical convention name for ``name`` (resolving aliases).

    Raises ValueError listing the valid names if ``name`` is unknown.
    """
    if isinstance(name, str):
        if name in CONVENTIONS:
            return name
        if name in CONVENTION_ALIASES:
            return CONVENTION_ALIASES[name]
    raise ValueError(f"unknown camera convention {name!r}; valid names: {', '.join(CONVENTION_NAMES)}")


def convention_to_opencv(name: str) -> np.ndarray:
    """Fixed transform T_cvcam_conv, shape (4, 4).

    Maps homogeneous coordinates expressed in the camera frame of convention
    ``name`` into OpenCV camera-frame coordinates (pure rotation, no translation).
    """
    T = np.eye(4)
    T[:3, :3] = _CONV_TO_CV_ROT[canonical_convention(name)]
    return T


# --------------------------------------------------------------------------- helpers


def as_float_array(x: Any) -> np.ndarray:
    """numpy float64 view/copy of an array-like or torch tensor."""
    if hasattr(x, "detach"):  # torch.Tensor, without importing torch
        x = x.detach().cpu()
    return np.asarray(x, dtype=np.float64)


def is_number(x: Any) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def is_int(x: Any) -> bool:
    if isinstance(x, (bool, np.bool_)):
        return False
    if isinstance(x, (int, np.integer)):
        return True
    return isinstance(x, (float, np.floating)) and math.isfinite(x) and float(x).is_integer()


def rigid_inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms, (..., 4, 4) -> (..., 4, 4)."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def rigid_problem(M: np.ndarray, tol: float = ORTHONORMAL_TOL) -> tuple[str, str] | None:
    """Why ``M`` is not a valid rigid 4x4 transform, as (expected, found), or None."""
    if M.shape != (4, 4):
        return "a 4x4 rigid transform", f"shape {M.shape}"
    if not np.all(np.isfinite(M)):
        return "a rigid transform of finite values", f"non-finite entries {M.tolist()}"
    if not np.allclose(M[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=1e-12):
        return "a rigid transform with last row [0, 0, 0, 1]", f"last row {M[3].tolist()}"
    R = M[:3, :3]
    dev = float(np.abs(R.T @ R - np.eye(3)).max())
    if dev > tol:
        return (
            f"a rigid transform with an orthonormal rotation block (max |R^T R - I| <= {tol:g})",
            f"max |R^T R - I| = {dev:.3g}",
        )
    det = float(np.linalg.det(R))
    if det < 0:
        return "a rigid transform with a proper rotation (det(R) = +1)", f"a reflection, det(R) = {det:.6g}"
    return None


def as_rigid_transforms(
    M: Any, source: str = "<matrix>", field: str = "extrinsic", tol: float = ORTHONORMAL_TOL
) -> np.ndarray:
    """Like :func:`as_rigid_transform` for one (4, 4) or a stack (T, 4, 4), T >= 1,
    checking each; an error names the first bad frame as ``field[t]``."""
    try:
        A = as_float_array(M)
    except (TypeError, ValueError) as e:
        raise CameraFileError(source, field, "a 4x4 or Tx4x4 numeric array", str(e)) from None
    if A.ndim == 3 and A.shape[1:] == (4, 4) and A.shape[0] >= 1:
        A = A.copy()
        R = A[:, :3, :3]
        with np.errstate(all="ignore"):
            dev = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(1, 2))
            bad = (
                ~np.isfinite(A).all(axis=(1, 2))
                | (np.abs(A[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) > 1e-12)
                | ~(dev <= tol)
                | (np.linalg.det(np.where(np.isfinite(R), R, 0.0)) < 0)
            )
        if bad.any():  # the first bad frame, reported by the one-matrix check
            t = int(np.argmax(bad))
            as_rigid_transform(A[t], source, f"{field}[{t}]", tol)
        fix = dev >= 1e-12  # re-orthonormalise (nearest rotation) where needed, as as_rigid_transform does
        if fix.any():
            U, _, Vt = np.linalg.svd(R[fix])
            A[fix, :3, :3] = U @ Vt
        return A
    if A.ndim == 3:
        raise CameraFileError(
            source, field, "one 4x4 rigid transform or one per frame, shape (T >= 1, 4, 4)", f"shape {A.shape}"
        )
    return as_rigid_transform(A, source, field, tol)


def as_rigid_transform(
    M: Any, source: str = "<matrix>", field: str = "extrinsic", tol: float = ORTHONORMAL_TOL
) -> np.ndarray:
    """A checked (4, 4) rigid transform: finite, last row [0, 0, 0, 1], rotation
    within ``tol`` of orthonormal (then replaced by the nearest rotation) and
    proper. Raises :class:`CameraFileError` naming ``source`` and ``field``.
    For dataset adapters whose calibrations are stored in low precision."""
    try:
        M = as_float_array(M).copy()
    except (TypeError, ValueError) as e:
        raise CameraFileError(source, field, "a 4x4 numeric matrix", str(e)) from None
    problem = rigid_problem(M, tol)
    if problem is not None:
        raise CameraFileError(source, field, *problem)
    M[:3, :3] = _nearest_rotation(M[:3, :3])
    return M


def _nearest_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation closest to ``R`` (Frobenius norm, via SVD); ``R`` itself when already orthonormal."""
    if np.abs(R.T @ R - np.eye(3)).max() < 1e-12:
        return R
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world (4, 4) of a camera at ``eye`` looking at ``target`` (metres), OpenCV axes.

    x right, y down, z forward; ``up`` is the world's up direction (the image's
    "up" lies in the plane of ``up`` and the viewing direction). Use it with
    ``Camera(..., direction="camera_to_world")`` (the default).
    """
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    norm = np.linalg.norm(x)
    if norm < 1e-9:
        raise ValueError(f"look_at: the viewing direction {z.tolist()} is parallel to up {up.tolist()}")
    x /= norm
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = eye
    return T


def rotation_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) @ Ry(pitch) @ Rx(roll), shape (3, 3); angles in radians."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def rotation_from_quat_xyzw(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """Rotation matrix (3, 3) of a unit quaternion given as (x, y, z, w)."""
    x, y, z, w = qx, qy, qz, qw
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
