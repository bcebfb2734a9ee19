"""Projection of 3D points through a camera: pinhole plus OpenCV distortion.

Units: metres in, pixels out (pixel centres at integer coordinates, see :mod:`oscar_core.camera.pinhole`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from .geometry import as_float_array
from .intrinsics import Intrinsics

__all__ = ["Projection", "Projector", "project", "project_points_cv"]


class Projector(Protocol):
    """What :func:`project` needs of a camera (:class:`~oscar_core.camera.pinhole.Camera` is one)."""

    intrinsics: Intrinsics

    @property
    def num_frames(self) -> int | None: ...

    def world_to_cv(self, mount_pose: Any = None) -> np.ndarray: ...


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
    P = as_float_array(points_cv)
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


def project(points: Any, camera: Projector, mount_pose: Any = None, near: float = 1e-6) -> Projection:
    """Project world points (metres) into ``camera``'s image.

    Static camera: ``points`` (..., 3) in the world / robot base frame.
    Mounted camera: ``mount_pose`` is T_world_link of the mount link, (T, 4, 4)
    with ``points`` (T, ..., 3) (one pose per leading index), or (4, 4) with
    ``points`` (..., 3).
    Camera with one extrinsic per frame (``camera.num_frames`` = T): ``points``
    (T, ..., 3), frame t projected through extrinsic t (and mount pose t).
    Returns a Projection (uv (..., 2) pixels, depth (...,) metres).
    """
    P = as_float_array(points)
    if P.shape[-1:] != (3,):
        raise ValueError(f"project: points must have shape (..., 3), found {P.shape}")
    M = camera.world_to_cv(mount_pose)
    R, t = M[..., :3, :3], M[..., :3, 3]
    if M.ndim == 3 and (P.ndim < 2 or P.shape[0] != M.shape[0]):
        why = (
            f"{camera.num_frames} per-frame extrinsics"
            if camera.num_frames is not None
            else f"mount_pose of shape {M.shape}"
        )
        raise ValueError(f"project: with {why}, points must have shape ({M.shape[0]}, ..., 3), found {P.shape}")
    with np.errstate(all="ignore"):  # NaN points pass through silently
        if M.ndim == 2:
            P_cv = P @ R.T + t
        else:
            P_cv = (P.reshape(M.shape[0], -1, 3) @ np.swapaxes(R, -1, -2) + t[:, None, :]).reshape(P.shape)
    return project_points_cv(P_cv, camera.intrinsics, near)
