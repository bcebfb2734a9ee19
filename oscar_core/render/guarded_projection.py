"""Projection for drawing: camera-frame points to pixels, guarded where a renderer needs it at the image's edges.

- a point beyond the radius where the lens model's radial distortion stops
  growing (strong distortion folds such points back into the image) is sent far
  out along its ray instead, so it can never wrap back in (:func:`project_cv`);
- a point counts as in front of the camera when its depth is above :data:`NEAR`.

Every condition renderer (skeleton, mesh, capsules) projects through these, so
the three agree pixel for pixel on where a point lands. Units: metres in,
pixels out (pixel centres at integer coordinates).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..camera import Intrinsics

__all__ = ["NEAR", "GuardedProjection", "distortion_valid_radius", "guarded_project", "project_cv", "to_camera"]

NEAR = 1e-6  # metres: a point is in front of the camera when its depth is > NEAR (as camera.project)


@functools.lru_cache(maxsize=256)
def distortion_valid_radius(distortion: tuple[float, ...]) -> float:
    """Largest normalised radius r = |(x/z, y/z)| up to which the radial model
    r · radial(r) still grows (inf when it grows everywhere up to r = 50).

    Beyond it the polynomial folds back: points further out would land nearer the
    centre, or on the opposite side. Tangential and thin-prism terms are small
    and ignored here.
    """
    if not distortion:
        return float("inf")
    k = tuple(distortion) + (0.0,) * (12 - len(distortion))
    k1, k2, _, _, k3, k4, k5, k6 = k[:8]
    r = np.concatenate([np.linspace(0.0, 2.0, 4001)[1:], np.geomspace(2.0, 50.0, 4000)[1:]])
    r2 = r * r
    with np.errstate(all="ignore"):
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        rd = r * radial
    grows = np.isfinite(rd) & (np.diff(np.concatenate([[0.0], rd])) > 0) & (radial > 0)
    bad = np.flatnonzero(~grows)
    if bad.size == 0:
        return float("inf")
    return float(r[bad[0] - 1]) if bad[0] > 0 else 0.0


@dataclass(frozen=True)
class GuardedProjection:
    """uv: (..., 2) pixels; depth: (...,) metres; in_front: (...,) bool (depth > NEAR and
    finite); in_image: (...,) bool (in front and inside the pixel-edge extent)."""

    uv: np.ndarray
    depth: np.ndarray
    in_front: np.ndarray
    in_image: np.ndarray


def project_cv(P: np.ndarray, intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Project camera-frame points (..., 3) metres with depth > 0 to pixels, guarded against the fold-back of
    strong distortion; returns (uv (..., 2) pixels, folded (...,) bool: beyond :func:`distortion_valid_radius`,
    sent far out along the ray)."""
    from ..camera import project_points_cv

    proj = project_points_cv(P, intr, near=NEAR)
    uv = proj.uv
    r_valid = distortion_valid_radius(tuple(intr.distortion))
    if not np.isfinite(r_valid):
        return uv, np.zeros(P.shape[:-1], bool)
    with np.errstate(all="ignore"):
        x, y = P[..., 0] / P[..., 2], P[..., 1] / P[..., 2]
        r = np.hypot(x, y)
        folded = np.isfinite(r) & (r > r_valid)
        if folded.any():
            # far out along the undistorted ray: never back inside the image
            far = 4.0 * (intr.width + intr.height) / (min(intr.fx, intr.fy) * np.maximum(r, 1e-12))
            s = np.maximum(1.0, far)
            lin = np.stack([intr.cx + intr.fx * x * s, intr.cy + intr.fy * y * s], axis=-1)
            uv = np.where(folded[..., None], lin, uv)
    return uv, folded


def guarded_project(points_cv, intr: Intrinsics) -> GuardedProjection:
    """Project camera-frame points (..., 3) metres (OpenCV: x right, y down, z forward)
    to pixels, without the fold-back of strong distortion (see module doc)."""
    P = np.asarray(points_cv, dtype=np.float64)
    uv, _ = project_cv(P, intr)
    z = P[..., 2]
    with np.errstate(invalid="ignore"):
        in_front = (z > NEAR) & np.isfinite(P).all(-1)
        u, v = uv[..., 0], uv[..., 1]
        in_image = in_front & (u >= -0.5) & (u < intr.width - 0.5) & (v >= -0.5) & (v < intr.height - 0.5)
    return GuardedProjection(uv, z, in_front, in_image)


def to_camera(points: np.ndarray, M: np.ndarray) -> np.ndarray:
    """World points (T, N, 3) → OpenCV camera frame with M (4, 4) or (T, 4, 4)."""
    R, t = M[..., :3, :3], M[..., :3, 3]
    with np.errstate(all="ignore"):
        if M.ndim == 2:
            return points @ R.T + t
        return points @ np.swapaxes(R, -1, -2) + t[:, None, :]
