"""Pinhole cameras with OpenCV distortion: calibration files and projection.

Units: lengths in metres, angles in radians, image quantities in pixels.
Pixel convention: pixel centres sit at integer coordinates, so pixel (0, 0)
covers [-0.5, 0.5) x [-0.5, 0.5) and a W x H image spans
[-0.5, W - 0.5) x [-0.5, H - 0.5).

Camera-frame conventions (``CONVENTIONS``)
------------------------------------------
``"opencv"``   (alias ``"ros_optical"``): x right, y down, z forward.
``"opengl"``   (alias ``"blender"``):     x right, y up, z backward.
``"ros_body"`` (alias ``"ros"``):         x forward, y left, z up (REP-103).

Camera JSON file
----------------
A camera file is one JSON object::

    {
      "image_size": [1280, 720],
      "intrinsics": {"fx": 600.0, "fy": 600.0, "cx": 640.0, "cy": 360.0},
      "distortion": [-0.05, 0.01, 0.0, 0.0, 0.0],
      "extrinsic": {"xyz_rpy": [0.5, 0.0, 1.2, 0.0, 0.6, 3.14159]},
      "convention": "opencv",
      "direction": "camera_to_world",
      "mount": null,
      "embodiment": "franka"
    }

Keys (any other top-level key is an error):

``image_size`` (required)
    ``[width, height]``, positive integers, pixels.
``intrinsics`` (required)
    ``{"fx", "fy", "cx", "cy"}`` in pixels, or ``{"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]}``
    (no skew).
``distortion`` (optional, default none)
    OpenCV coefficients ``k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4]]]``:
    4, 5, 8 or 12 numbers. The 14-coefficient tilted model is not supported.
``extrinsic`` (required) -- exactly one of
    ``{"matrix": 4x4 nested list}``;
    ``{"xyz_rpy": [x, y, z, roll, pitch, yaw]}`` metres / radians with
    ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (fixed-axis XYZ, the same as
    ``scipy.spatial.transform.Rotation.from_euler("xyz", [roll, pitch, yaw])``);
    ``{"xyz_quat_xyzw": [x, y, z, qx, qy, qz, qw]}`` (the quaternion norm must be
    within 1e-3 of 1; it is then normalised).
    Per frame (a camera that moves: a head camera given per frame, egocentric
    video): the same keys holding one value per video frame, ``{"matrix":
    [4x4, 4x4, ...]}`` (T, 4, 4), ``{"xyz_rpy": [[...6], ...]}`` (T, 6) or
    ``{"xyz_quat_xyzw": [[...7], ...]}`` (T, 7). T must equal the trajectory's
    frame count. With ``mount: null`` each is the camera in the world / base
    frame at that frame; with a mount link, its offset from the link at that frame.
``convention`` (optional, default ``"opencv"``)
    Axes of the camera frame the extrinsic refers to; see above.
``direction`` (optional, default ``"camera_to_world"``)
    ``"camera_to_world"``: the extrinsic is the camera pose in the reference
    frame (T_ref_cam). ``"world_to_camera"``: it maps reference-frame points into
    the camera frame (T_cam_ref).
``mount`` (optional, default ``null``)
    ``null`` or ``"static"``: the reference frame is the robot base / world frame.
    ``{"link": "head_link"}``: the reference frame is that link's frame and the
    camera moves with it; the link's world pose must be supplied per frame.
``embodiment`` (optional)
    Name of the embodiment this calibration was made for (a string).

``save_camera`` always writes the ``matrix`` extrinsic form (per frame when
the camera has one extrinsic per frame).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from oscar_core._atomic import atomic_write_bytes
from oscar_core.errors import CameraFileError

__all__ = [
    "CONVENTIONS",
    "CONVENTION_ALIASES",
    "DIRECTIONS",
    "Intrinsics",
    "Camera",
    "Projection",
    "canonical_convention",
    "as_rigid_transform",
    "as_rigid_transforms",
    "look_at",
    "convention_to_opencv",
    "project",
    "project_points_cv",
    "load_camera",
    "save_camera",
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

_VALID_CONVENTION_NAMES = tuple(CONVENTIONS) + tuple(CONVENTION_ALIASES)
_DISTORTION_LENGTHS = (0, 4, 5, 8, 12)
_ORTHONORMAL_TOL = 1e-4  # float32-stored calibrations (RH20T, InternData) deviate by ~1e-5


def canonical_convention(name: str) -> str:
    """Return the canonical convention name for ``name`` (resolving aliases).

    Raises ValueError listing the valid names if ``name`` is unknown.
    """
    if isinstance(name, str):
        if name in CONVENTIONS:
            return name
        if name in CONVENTION_ALIASES:
            return CONVENTION_ALIASES[name]
    raise ValueError(
        f"unknown camera convention {name!r}; valid names: {', '.join(_VALID_CONVENTION_NAMES)}"
    )


def convention_to_opencv(name: str) -> np.ndarray:
    """Fixed transform T_cvcam_conv, shape (4, 4).

    Maps homogeneous coordinates expressed in the camera frame of convention
    ``name`` into OpenCV camera-frame coordinates (pure rotation, no translation).
    """
    T = np.eye(4)
    T[:3, :3] = _CONV_TO_CV_ROT[canonical_convention(name)]
    return T


# --------------------------------------------------------------------------- helpers


def _as_float_array(x: Any) -> np.ndarray:
    """numpy float64 view/copy of an array-like or torch tensor."""
    if hasattr(x, "detach"):  # torch.Tensor, without importing torch
        x = x.detach().cpu()
    return np.asarray(x, dtype=np.float64)


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def _is_int(x: Any) -> bool:
    if isinstance(x, (bool, np.bool_)):
        return False
    if isinstance(x, (int, np.integer)):
        return True
    return isinstance(x, (float, np.floating)) and math.isfinite(x) and float(x).is_integer()


def _rigid_inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms, (..., 4, 4) -> (..., 4, 4)."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def _rigid_problem(M: np.ndarray, tol: float = _ORTHONORMAL_TOL) -> tuple[str, str] | None:
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


def as_rigid_transforms(M: Any, source: str = "<matrix>", field: str = "extrinsic",
                        tol: float = _ORTHONORMAL_TOL) -> np.ndarray:
    """Like :func:`as_rigid_transform` for one (4, 4) or a stack (T, 4, 4), T >= 1,
    checking each; an error names the first bad frame as ``field[t]``."""
    try:
        A = _as_float_array(M)
    except (TypeError, ValueError) as e:
        raise CameraFileError(source, field, "a 4x4 or Tx4x4 numeric array", str(e)) from None
    if A.ndim == 3 and A.shape[1:] == (4, 4) and A.shape[0] >= 1:
        A = A.copy()
        R = A[:, :3, :3]
        with np.errstate(all="ignore"):
            dev = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(1, 2))
            bad = (~np.isfinite(A).all(axis=(1, 2)) | (np.abs(A[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) > 1e-12)
                   | ~(dev <= tol) | (np.linalg.det(np.where(np.isfinite(R), R, 0.0)) < 0))
        if bad.any():  # the first bad frame, reported by the one-matrix check
            t = int(np.argmax(bad))
            as_rigid_transform(A[t], source, f"{field}[{t}]", tol)
        fix = dev >= 1e-12  # re-orthonormalise (nearest rotation) where needed, as as_rigid_transform does
        if fix.any():
            U, _, Vt = np.linalg.svd(R[fix])
            A[fix, :3, :3] = U @ Vt
        return A
    if A.ndim == 3:
        raise CameraFileError(source, field, "one 4x4 rigid transform or one per frame, shape (T >= 1, 4, 4)",
                              f"shape {A.shape}")
    return as_rigid_transform(A, source, field, tol)


def as_rigid_transform(M: Any, source: str = "<matrix>", field: str = "extrinsic",
                       tol: float = _ORTHONORMAL_TOL) -> np.ndarray:
    """A checked (4, 4) rigid transform: finite, last row [0, 0, 0, 1], rotation
    within ``tol`` of orthonormal (then replaced by the nearest rotation) and
    proper. Raises :class:`CameraFileError` naming ``source`` and ``field``.
    For dataset adapters whose calibrations are stored in low precision."""
    try:
        M = _as_float_array(M).copy()
    except (TypeError, ValueError) as e:
        raise CameraFileError(source, field, "a 4x4 numeric matrix", str(e)) from None
    problem = _rigid_problem(M, tol)
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


# --------------------------------------------------------------------------- intrinsics


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics with OpenCV distortion.

    fx, fy: focal lengths, pixels (> 0). cx, cy: principal point, pixels, with
    pixel centres at integer coordinates. width, height: image size, pixels.
    distortion: OpenCV coefficients k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4]]]
    (length 0, 4, 5, 8 or 12). They act on normalised image coordinates.

    Invalid values raise CameraFileError (a ValueError) naming the field.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        src = "<Intrinsics>"
        for name in ("fx", "fy"):
            v = getattr(self, name)
            if not _is_number(v) or not math.isfinite(v) or v <= 0:
                raise CameraFileError(src, name, "a positive finite number (pixels)", repr(v))
            object.__setattr__(self, name, float(v))
        for name in ("cx", "cy"):
            v = getattr(self, name)
            if not _is_number(v) or not math.isfinite(v):
                raise CameraFileError(src, name, "a finite number (pixels)", repr(v))
            object.__setattr__(self, name, float(v))
        for name in ("width", "height"):
            v = getattr(self, name)
            if not _is_int(v) or v <= 0:
                raise CameraFileError(src, name, "a positive integer (pixels)", repr(v))
            object.__setattr__(self, name, int(v))
        d = self.distortion
        try:
            d = tuple(d)
        except TypeError:
            raise CameraFileError(src, "distortion", "a sequence of numbers", repr(d)) from None
        if len(d) == 14:
            raise CameraFileError(
                src, "distortion",
                "0, 4, 5, 8 or 12 coefficients (the 14-coefficient tilted model is not supported)",
                "14 coefficients",
            )
        if len(d) not in _DISTORTION_LENGTHS:
            raise CameraFileError(src, "distortion", "0, 4, 5, 8 or 12 coefficients", f"{len(d)} coefficients")
        if not all(_is_number(c) and math.isfinite(c) for c in d):
            raise CameraFileError(src, "distortion", "finite numbers", repr(list(d)))
        object.__setattr__(self, "distortion", tuple(float(c) for c in d))

    def matrix(self) -> np.ndarray:
        """Camera matrix K, shape (3, 3), pixels."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def crop(self, x0: float, y0: float, w: int, h: int) -> "Intrinsics":
        """Intrinsics of the sub-image of size (w, h) whose top-left pixel is (x0, y0).

        A point at pixel (u, v) in this image is at (u - x0, v - y0) in the crop.
        Distortion coefficients are unchanged.
        """
        return replace(self, cx=self.cx - x0, cy=self.cy - y0, width=w, height=h)

    def _scaled(self, sx: float, sy: float, width: int, height: int) -> "Intrinsics":
        # Pixel centres at integer coordinates: scaling by s maps c -> (c + 0.5) * s - 0.5.
        return replace(
            self,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=width,
            height=height,
        )

    def resized(self, width: int, height: int, mode: str = "crop") -> "Intrinsics":
        """Intrinsics for an output image of ``width`` x ``height`` pixels.

        mode "crop": centre-crop the source image to the target aspect ratio (the
        crop offset may be fractional), then scale uniformly by s.
        mode "stretch": scale x by width / self.width and y by height / self.height.
        Scaling uses pixel centres at integer coordinates: c -> (c + 0.5) * s - 0.5,
        f -> f * s. Distortion coefficients are unchanged: they act on normalised
        coordinates, which resizing does not alter.
        """
        if not _is_int(width) or not _is_int(height) or width <= 0 or height <= 0:
            raise ValueError(f"resized: expected positive integer width and height, found {width!r}, {height!r}")
        width, height = int(width), int(height)
        W, H = self.width, self.height
        if mode == "stretch":
            return self._scaled(width / W, height / H, width, height)
        if mode != "crop":
            raise ValueError(f"resized: mode must be 'crop' or 'stretch', found {mode!r}")
        target_aspect = width / height
        if W / H > target_aspect:  # source too wide: crop columns
            cw, ch = H * target_aspect, float(H)
        else:  # source too tall: crop rows
            cw, ch = float(W), W / target_aspect
        x0, y0 = (W - cw) / 2.0, (H - ch) / 2.0
        s = width / cw
        cropped = replace(self, cx=self.cx - x0, cy=self.cy - y0)
        return cropped._scaled(s, s, width, height)


# --------------------------------------------------------------------------- camera


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera.

    intrinsics: Intrinsics.
    extrinsic: (4, 4) rigid transform exactly as the user gave it (stored as a
        read-only float64 copy), or (T, 4, 4), one per video frame, for a camera
        that moves (``num_frames`` is then T); its camera frame uses
        ``convention`` axes and its meaning is set by ``direction``.
    convention: camera-frame axes, a name or alias from CONVENTIONS (stored canonical).
    direction: "camera_to_world" (extrinsic = T_ref_cam, the camera pose) or
        "world_to_camera" (extrinsic = T_cam_ref).
    mount_link: None -> the reference frame is the world / robot base and the camera
        is static; a link name -> the reference frame is that link's frame and the
        link's world pose must be passed per frame (``mount_pose``).
    embodiment: optional name of the embodiment the calibration is for.
    """

    intrinsics: Intrinsics
    extrinsic: np.ndarray
    convention: str = "opencv"
    direction: str = "camera_to_world"
    mount_link: str | None = None
    embodiment: str | None = None
    _cv_from_ref: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        src = "<Camera>"
        if not isinstance(self.intrinsics, Intrinsics):
            raise CameraFileError(src, "intrinsics", "an Intrinsics instance", type(self.intrinsics).__name__)
        M = as_rigid_transforms(self.extrinsic, src, "extrinsic")
        M.setflags(write=False)
        object.__setattr__(self, "extrinsic", M)
        if not isinstance(self.convention, str) or self.convention not in _VALID_CONVENTION_NAMES:
            raise CameraFileError(src, "convention", f"one of {list(_VALID_CONVENTION_NAMES)}", repr(self.convention))
        object.__setattr__(self, "convention", canonical_convention(self.convention))
        if self.direction not in DIRECTIONS:
            raise CameraFileError(src, "direction", f"one of {list(DIRECTIONS)}", repr(self.direction))
        if self.mount_link is not None and (not isinstance(self.mount_link, str) or not self.mount_link):
            raise CameraFileError(src, "mount_link", "None or a non-empty link name", repr(self.mount_link))
        if self.embodiment is not None and not isinstance(self.embodiment, str):
            raise CameraFileError(src, "embodiment", "None or a string", repr(self.embodiment))

        C = convention_to_opencv(self.convention)  # T_cv_conv
        if self.direction == "camera_to_world":  # M = T_ref_conv
            cv_from_ref = C @ _rigid_inverse(M)
        else:  # M = T_conv_ref
            cv_from_ref = C @ M
        cv_from_ref.setflags(write=False)
        object.__setattr__(self, "_cv_from_ref", cv_from_ref)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        return (
            self.intrinsics == other.intrinsics
            and np.array_equal(self.extrinsic, other.extrinsic)
            and (self.convention, self.direction, self.mount_link, self.embodiment)
            == (other.convention, other.direction, other.mount_link, other.embodiment)
        )

    __hash__ = None  # type: ignore[assignment]  # holds an array

    @property
    def is_static(self) -> bool:
        """True when the camera is fixed in the world frame (no mount link, one extrinsic)."""
        return self.mount_link is None and self.extrinsic.ndim == 2

    @property
    def num_frames(self) -> int | None:
        """T for a camera with one extrinsic per frame, None for one extrinsic for all frames."""
        return int(self.extrinsic.shape[0]) if self.extrinsic.ndim == 3 else None

    def check_frames(self, num_frames: int, source: str = "<camera>") -> None:
        """Raise :class:`CameraFileError` unless a per-frame camera has exactly ``num_frames`` extrinsics."""
        n = self.num_frames
        if n is not None and n != int(num_frames):
            raise CameraFileError(source, "extrinsic", f"{int(num_frames)} per-frame extrinsics, one per trajectory frame",
                                  f"{n} extrinsics")

    def time_slice(self, start: int | None = None, stop: int | None = None) -> "Camera":
        """The camera for frames ``start:stop`` (as ``Trajectory.time_slice``); itself when it has one extrinsic."""
        if self.num_frames is None:
            return self
        return replace(self, extrinsic=self.extrinsic[start:stop])

    def world_to_cv(self, mount_pose: Any = None) -> np.ndarray:
        """T_cv_world: maps world points (metres) into the OpenCV camera frame.

        Static camera: call without ``mount_pose``; returns (4, 4), or (T, 4, 4)
        for a camera with one extrinsic per frame.
        Mounted camera: ``mount_pose`` is the world pose T_world_link of
        ``mount_link``, (4, 4) or (T, 4, 4); returns the same shape ((T, 4, 4)
        for a per-frame camera, whose T must match).
        Passing a mount pose to a static camera, or none to a mounted one, raises.
        """
        if self.mount_link is None:
            if mount_pose is not None:
                raise ValueError(
                    "world_to_cv: this camera is static (mount_link is None) but a mount_pose was given; "
                    "set mount_link on the camera or drop mount_pose"
                )
            return self._cv_from_ref.copy()
        if mount_pose is None:
            raise ValueError(
                f"world_to_cv: the camera is mounted on link {self.mount_link!r}; "
                "pass that link's world pose as mount_pose, shape (4, 4) or (T, 4, 4)"
            )
        P = _as_float_array(mount_pose)
        if P.ndim not in (2, 3) or P.shape[-2:] != (4, 4):
            raise ValueError(f"world_to_cv: mount_pose must have shape (4, 4) or (T, 4, 4), found {P.shape}")
        n = self.num_frames
        if n is not None and P.ndim == 3 and P.shape[0] != n:
            raise ValueError(f"world_to_cv: this camera has {n} per-frame extrinsics but mount_pose has "
                             f"{P.shape[0]} frames, shape {P.shape}")
        return self._cv_from_ref @ _rigid_inverse(P)

    def resized(self, width: int, height: int, mode: str = "crop") -> "Camera":
        """Camera with intrinsics resized for a ``width`` x ``height`` image (see Intrinsics.resized)."""
        return replace(self, intrinsics=self.intrinsics.resized(width, height, mode))

    def to_dict(self) -> dict:
        """JSON-ready dict in the camera file format (extrinsic in ``matrix`` form)."""
        i = self.intrinsics
        return {
            "image_size": [i.width, i.height],
            "intrinsics": {"fx": i.fx, "fy": i.fy, "cx": i.cx, "cy": i.cy},
            "distortion": list(i.distortion),
            "extrinsic": {"matrix": self.extrinsic.tolist()},
            "convention": self.convention,
            "direction": self.direction,
            "mount": None if self.mount_link is None else {"link": self.mount_link},
            "embodiment": self.embodiment,
        }

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "<dict>", defaults: Any = None) -> "Camera":
        """Build a Camera from a dict in the camera file format.

        ``source`` names the file (or object) in error messages. ``defaults``
        (e.g. an embodiment's ``CameraSpec``) supplies ``convention`` and
        ``direction`` when the dict omits them. Raises CameraFileError naming
        the source, the field, what was expected and found.
        """
        return _parse_camera(d, str(source), defaults)


# --------------------------------------------------------------------------- file parsing

_TOP_KEYS = ("image_size", "intrinsics", "distortion", "extrinsic", "convention", "direction", "mount", "embodiment")
_EXTRINSIC_FORMS = ("matrix", "xyz_rpy", "xyz_quat_xyzw")


def _short(x: Any, limit: int = 120) -> str:
    s = json.dumps(x) if isinstance(x, (dict, list, str, int, float, bool, type(None))) else repr(x)
    return s if len(s) <= limit else s[: limit - 3] + "..."


def _number(src: str, fieldname: str, v: Any) -> float:
    if not _is_number(v) or not math.isfinite(v):
        raise CameraFileError(src, fieldname, "a finite number", _short(v))
    return float(v)


def _vector(src: str, fieldname: str, v: Any, n: int, what: str) -> list[float]:
    if not isinstance(v, (list, tuple)) or len(v) != n:
        found = f"a list of length {len(v)}" if isinstance(v, (list, tuple)) else _short(v)
        raise CameraFileError(src, fieldname, f"a list of {n} numbers {what}", found)
    return [_number(src, f"{fieldname}[{k}]", x) for k, x in enumerate(v)]


def _matrix(src: str, fieldname: str, v: Any, rows: int, cols: int) -> np.ndarray:
    ok = isinstance(v, (list, tuple)) and len(v) == rows and all(
        isinstance(r, (list, tuple)) and len(r) == cols for r in v
    )
    if not ok:
        try:
            found = f"shape {np.asarray(v, dtype=object).shape}"
        except Exception:  # ragged nesting
            found = _short(v)
        raise CameraFileError(src, fieldname, f"a {rows}x{cols} nested list of numbers", found)
    return np.array([[_number(src, f"{fieldname}[{r}][{c}]", x) for c, x in enumerate(row)] for r, row in enumerate(v)])


def _parse_intrinsics(d: Mapping, src: str) -> Intrinsics:
    size = d["image_size"]
    if not isinstance(size, (list, tuple)) or len(size) != 2 or not all(_is_int(s) and s > 0 for s in size):
        raise CameraFileError(src, "image_size", "[width, height] as two positive integers (pixels)", _short(size))
    width, height = int(size[0]), int(size[1])

    intr = d["intrinsics"]
    if not isinstance(intr, Mapping):
        raise CameraFileError(src, "intrinsics", 'an object {"fx","fy","cx","cy"} or {"K"}', _short(intr))
    if "K" in intr:
        if set(intr) != {"K"}:
            raise CameraFileError(src, "intrinsics", 'either only "K" or only "fx","fy","cx","cy"', f"keys {sorted(intr)}")
        K = _matrix(src, "intrinsics.K", intr["K"], 3, 3)
        if K[0, 1] != 0 or K[1, 0] != 0 or not np.allclose(K[2], [0, 0, 1], rtol=0, atol=1e-12):
            raise CameraFileError(src, "intrinsics.K", "[[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)", K.tolist())
        values = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
        names = dict.fromkeys(values, "intrinsics.K")
    else:
        want = ("fx", "fy", "cx", "cy")
        missing = [k for k in want if k not in intr]
        extra = sorted(set(intr) - set(want))
        if missing or extra:
            found = f"missing {missing}" if missing else f"unknown keys {extra}"
            raise CameraFileError(src, "intrinsics", 'keys "fx", "fy", "cx", "cy" (or only "K")', found)
        values = {k: _number(src, f"intrinsics.{k}", intr[k]) for k in want}
        names = {k: f"intrinsics.{k}" for k in want}
    for k in ("fx", "fy"):
        if values[k] <= 0:
            raise CameraFileError(src, names[k], f"a positive focal length {k} (pixels)", _short(float(values[k])))

    dist = d.get("distortion")
    if dist is None:
        dist = []
    if not isinstance(dist, (list, tuple)):
        raise CameraFileError(src, "distortion", "a list of 4, 5, 8 or 12 numbers", _short(dist))
    dist = [_number(src, f"distortion[{k}]", x) for k, x in enumerate(dist)]
    try:
        return Intrinsics(values["fx"], values["fy"], values["cx"], values["cy"], width, height, tuple(dist))
    except CameraFileError as e:  # distortion length, mostly; re-label with the file
        raise CameraFileError(src, names.get(e.field, e.field), e.expected, e.found) from None


def _per_frame(form: str, value: Any) -> bool:
    """True when ``value`` nests one level deeper than one extrinsic of ``form``."""
    depth = 3 if form == "matrix" else 2
    node = value
    for _ in range(depth):
        if not isinstance(node, (list, tuple)) or not node:
            return False
        node = node[0]
    return True


def _parse_extrinsic(v: Any, src: str) -> np.ndarray:
    """(4, 4), or (T, 4, 4) when the form holds one value per frame."""
    if not isinstance(v, Mapping) or len(v) != 1 or next(iter(v)) not in _EXTRINSIC_FORMS:
        found = f"keys {sorted(v)}" if isinstance(v, Mapping) else _short(v)
        raise CameraFileError(src, "extrinsic", f"an object with exactly one of the keys {list(_EXTRINSIC_FORMS)}", found)
    form, value = next(iter(v.items()))
    if _per_frame(form, value):
        fast = _per_frame_fast(form, value)
        if fast is not None:
            return fast
        # slow path: one frame at a time, so that an error names the frame and the entry
        return np.stack([_parse_one_extrinsic(form, item, f"extrinsic.{form}[{t}]", src) for t, item in enumerate(value)])
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
        ok = (np.abs(A[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) <= 1e-12) & (dev <= _ORTHONORMAL_TOL) & (np.linalg.det(R) >= 0)
        return A if ok.all() else None
    if A.ndim != 2 or A.shape[1] != width:
        return None
    M = np.tile(np.eye(4), (len(A), 1, 1))
    M[:, :3, 3] = A[:, :3]
    if form == "xyz_rpy":
        r, p, y = A[:, 3], A[:, 4], A[:, 5]
        cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
        M[:, :3, :3] = np.stack([
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1)], axis=1)
    else:
        q = A[:, 3:]
        n = np.linalg.norm(q, axis=1)
        if (np.abs(n - 1.0) > 1e-3).any():
            return None
        x, y, z, w = (q / n[:, None]).T
        M[:, :3, :3] = np.stack([
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], axis=1)
    return M


def _parse_one_extrinsic(form: str, value: Any, fname: str, src: str) -> np.ndarray:
    if form == "matrix":
        M = _matrix(src, fname, value, 4, 4)
        problem = _rigid_problem(M)
        if problem is not None:
            raise CameraFileError(src, fname, *problem)
        return M
    M = np.eye(4)
    if form == "xyz_rpy":
        x, y, z, roll, pitch, yaw = _vector(src, fname, value, 6, "[x, y, z, roll, pitch, yaw] (metres, radians)")
        M[:3, :3] = rotation_from_rpy(roll, pitch, yaw)
    else:
        x, y, z, qx, qy, qz, qw = _vector(src, fname, value, 7, "[x, y, z, qx, qy, qz, qw] (metres)")
        n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
        if abs(n - 1.0) > 1e-3:
            raise CameraFileError(src, fname, "a unit quaternion (norm within 1e-3 of 1)", f"norm {n:.6g}")
        M[:3, :3] = rotation_from_quat_xyzw(qx / n, qy / n, qz / n, qw / n)
    M[:3, 3] = (x, y, z)
    return M


def _parse_camera(d: Any, src: str, defaults: Any = None) -> Camera:
    if not isinstance(d, Mapping):
        raise CameraFileError(src, "<document>", "a JSON object", type(d).__name__)
    unknown = sorted(set(d) - set(_TOP_KEYS))
    if unknown:
        raise CameraFileError(src, unknown[0], f"only the keys {list(_TOP_KEYS)}", f"unknown keys {unknown}")
    required = {
        "image_size": "[width, height] in pixels",
        "intrinsics": '{"fx", "fy", "cx", "cy"} or {"K"}',
        "extrinsic": '{"matrix"}, {"xyz_rpy"} or {"xyz_quat_xyzw"}',
    }
    for key, what in required.items():
        if key not in d:
            raise CameraFileError(src, key, f"the required key {key!r}: {what}", "no such key")
    intrinsics = _parse_intrinsics(d, src)
    extrinsic = _parse_extrinsic(d["extrinsic"], src)

    convention = d.get("convention", getattr(defaults, "convention", "opencv"))
    if convention not in _VALID_CONVENTION_NAMES:
        raise CameraFileError(src, "convention", f"one of {list(_VALID_CONVENTION_NAMES)}", _short(convention))
    direction = d.get("direction", getattr(defaults, "direction", "camera_to_world"))
    if direction not in DIRECTIONS:
        raise CameraFileError(src, "direction", f"one of {list(DIRECTIONS)}", _short(direction))

    mount = d.get("mount")
    if mount is None or mount == "static":
        mount_link = None
    elif isinstance(mount, Mapping) and set(mount) == {"link"} and isinstance(mount["link"], str) and mount["link"]:
        mount_link = mount["link"]
    else:
        raise CameraFileError(src, "mount", 'null, "static" or {"link": "<link name>"}', _short(mount))

    embodiment = d.get("embodiment")
    if embodiment is not None and not isinstance(embodiment, str):
        raise CameraFileError(src, "embodiment", "a string or null", _short(embodiment))
    return Camera(intrinsics, extrinsic, convention, direction, mount_link, embodiment)


def load_camera(path: str | os.PathLike, defaults: Any = None) -> Camera:
    """Read a camera JSON file (format in the module docstring).

    defaults: an object with ``convention`` and ``direction`` attributes (an
    embodiment's ``CameraSpec``) used when the file omits those keys; without
    it they default to ``"opencv"`` and ``"camera_to_world"``.

    Raises CameraFileError for bad content (invalid JSON reports line and column);
    OSError (e.g. FileNotFoundError) if the file cannot be read.
    """
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise CameraFileError(path, "<document>", "valid JSON", f"{e.msg} at line {e.lineno}, column {e.colno}") from None
    return _parse_camera(d, str(path), defaults)


def save_camera(camera: Camera, path: str | os.PathLike) -> None:
    """Write ``camera`` as JSON to ``path`` atomically (temp file in the same directory, then rename).

    Raises OutputPathError if the directory does not exist or cannot be written;
    no temporary file is left behind.
    """
    text = json.dumps(camera.to_dict(), indent=2, allow_nan=False) + "\n"
    atomic_write_bytes(path, text.encode("utf-8"))


# --------------------------------------------------------------------------- projection


@dataclass(frozen=True, eq=False)
class Projection:
    """Result of projecting N-d batches of 3D points.

    uv: (..., 2) float64 pixels (pixel centres at integer coordinates). Only
        meaningful where ``in_front``; NaN for NaN input.
    depth: (...,) metres along the OpenCV optical axis (camera-frame z).
    in_front: (...,) bool, depth > near.
    in_image: (...,) bool, in_front and -0.5 <= u < width - 0.5 and
        -0.5 <= v < height - 0.5 (the image's pixel-edge extent).
    """

    uv: np.ndarray
    depth: np.ndarray
    in_front: np.ndarray
    in_image: np.ndarray

    @property
    def visible(self) -> np.ndarray:
        """Same as ``in_image``."""
        return self.in_image


def project_points_cv(points_cv: Any, intrinsics: Intrinsics, near: float = 1e-6) -> Projection:
    """Project points given in the OpenCV camera frame.

    points_cv: (..., 3) metres (x right, y down, z forward). Returns a Projection
    with uv (..., 2) pixels. Uses OpenCV's model: rational radial k1..k6,
    tangential p1, p2, thin prism s1..s4.
    """
    P = _as_float_array(points_cv)
    if P.shape[-1:] != (3,):
        raise ValueError(f"project_points_cv: points must have shape (..., 3), found {P.shape}")
    i = intrinsics
    with np.errstate(all="ignore"):
        z = P[..., 2]
        x = P[..., 0] / z
        y = P[..., 1] / z
        d = i.distortion
        if d:
            k = d + (0.0,) * (12 - len(d))
            k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = k
            x2, y2, xy = x * x, y * y, x * y
            r2 = x2 + y2
            r4 = r2 * r2
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            if k4 or k5 or k6:
                radial = radial / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
            xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2)
            yd = y * radial + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy
            if s1 or s2 or s3 or s4:
                xd = xd + s1 * r2 + s2 * r4
                yd = yd + s3 * r2 + s4 * r4
            x, y = xd, yd
        uv = np.empty(P.shape[:-1] + (2,))
        uv[..., 0] = i.fx * x + i.cx
        uv[..., 1] = i.fy * y + i.cy
        in_front = z > near
        u, v = uv[..., 0], uv[..., 1]
        in_image = in_front & (u >= -0.5) & (u < i.width - 0.5) & (v >= -0.5) & (v < i.height - 0.5)
    return Projection(uv=uv, depth=z.copy(), in_front=in_front, in_image=in_image)


def project(points: Any, camera: Camera, mount_pose: Any = None, near: float = 1e-6) -> Projection:
    """Project world points (metres) into ``camera``'s image.

    Static camera: ``points`` (..., 3) in the world / robot base frame.
    Mounted camera: ``mount_pose`` is T_world_link of the mount link, (T, 4, 4)
    with ``points`` (T, ..., 3) (one pose per leading index), or (4, 4) with
    ``points`` (..., 3).
    Camera with one extrinsic per frame (``camera.num_frames`` = T): ``points``
    (T, ..., 3), frame t projected through extrinsic t (and mount pose t).
    Returns a Projection (uv (..., 2) pixels, depth (...,) metres).
    """
    P = _as_float_array(points)
    if P.shape[-1:] != (3,):
        raise ValueError(f"project: points must have shape (..., 3), found {P.shape}")
    M = camera.world_to_cv(mount_pose)
    R, t = M[..., :3, :3], M[..., :3, 3]
    if M.ndim == 3 and (P.ndim < 2 or P.shape[0] != M.shape[0]):
        why = (f"{camera.num_frames} per-frame extrinsics" if camera.num_frames is not None
               else f"mount_pose of shape {M.shape}")
        raise ValueError(f"project: with {why}, points must have shape ({M.shape[0]}, ..., 3), found {P.shape}")
    with np.errstate(all="ignore"):  # NaN points pass through silently
        if M.ndim == 2:
            P_cv = P @ R.T + t
        else:
            P_cv = (P.reshape(M.shape[0], -1, 3) @ np.swapaxes(R, -1, -2) + t[:, None, :]).reshape(P.shape)
    return project_points_cv(P_cv, camera.intrinsics, near)
