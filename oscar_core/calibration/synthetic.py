"""Synthetic calibration problems with a known answer: a trajectory, a camera, and noisy pixel points.

Used by the tests and ``benchmarks/calibration.py`` to measure how well
:func:`oscar_core.calibration.pnp.calibrate` recovers a camera it did not see.
"""

from __future__ import annotations

import numpy as np

from ..camera import Camera, Intrinsics, look_at, project
from ..kinematics.trajectory import Trajectory, interpolate_keyframes
from ..kinematics.workspace import joint_limits, openness_to_signal
from .pnp import skeleton_points
from .points import PixelPoints

__all__ = ["SIZE", "random_trajectory", "problem", "observe"]

#: (width, height) of the synthetic camera's image, pixels
SIZE = (640, 480)


def random_trajectory(
    embodiment,
    rng: np.random.Generator,
    keys: int = 5,
    frames_per_key: int = 12,
    fps: float = 10.0,
    shrink: float = 0.15,
) -> Trajectory:
    """A smooth joint trajectory of ``(keys - 1) · frames_per_key + 1`` frames through ``keys`` random
    configurations drawn uniformly inside the joint limits shrunk by ``shrink`` of each range; grippers open."""
    lo, hi = joint_limits(embodiment, shrink)
    q = interpolate_keyframes(rng.uniform(lo, hi, size=(keys, len(lo))), frames_per_key)
    gripper = openness_to_signal(embodiment, np.ones((len(q), len(embodiment.grippers))))
    return Trajectory(embodiment.joint_names, q, fps, gripper, embodiment.gripper_names or None, source="<synthetic>")


def problem(
    embodiment, seed: int, sigma_px: float = 1.0, *, every: int = 4, keep: float = 0.8
) -> tuple[Trajectory, Camera, PixelPoints]:
    """Synthetic problem ``seed`` of ``embodiment`` with clicking noise ``sigma_px``: (trajectory, true camera,
    observed points).

    The trajectory is :func:`random_trajectory` (49 frames); the camera is 640 x 480 px with fx = fy = 600 px
    and the principal point at the centre, 1.6–2.0 m from the point (0.3, 0, 0.4) m it looks at, from an
    azimuth within ±60° of the x axis and an elevation of 20–40°; the points are :func:`observe`'s on every
    ``every``-th frame with ``keep`` of the visible points. The trajectory and camera depend on
    (embodiment, seed) only; the points on ``sigma_px`` too.
    """
    salt = sum(map(ord, embodiment.name))
    rng = np.random.default_rng([seed, salt])
    traj = random_trajectory(embodiment, rng)
    az, el, dist = rng.uniform(-np.pi / 3, np.pi / 3), np.deg2rad(rng.uniform(20, 40)), rng.uniform(1.6, 2.0)
    target = np.array([0.3, 0.0, 0.4])
    eye = target + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    cam = Camera(Intrinsics(600.0, 600.0, 319.5, 239.5, *SIZE), look_at(eye, target), embodiment=embodiment.name)
    noise = np.random.default_rng([seed, salt, int(round(sigma_px * 1000))])
    points = observe(embodiment, traj, cam, noise, sigma_px, frames=np.arange(0, len(traj), every), keep=keep)
    return traj, cam, points


def observe(
    embodiment,
    traj: Trajectory,
    camera: Camera,
    rng: np.random.Generator,
    sigma_px: float = 0.0,
    *,
    frames=None,
    keep: float = 1.0,
    margin_px: float = 1.0,
) -> PixelPoints:
    """What a person (or a keypoint detector) would click: the skeleton points of ``frames`` (default:
    every frame) projected through ``camera``, plus Gaussian noise of ``sigma_px`` pixels per axis.

    keep: fraction of the visible points kept (the others are missing, at random); points behind the
    camera or within ``margin_px`` of the image's edge (after the noise) are left out.
    """
    P = skeleton_points(embodiment, traj)
    T, K = P.shape[:2]
    frames = np.arange(T) if frames is None else np.asarray(frames, dtype=np.int64)
    names = tuple(embodiment.skeleton.links)
    pr = project(P[frames], camera)
    uv = pr.uv + rng.normal(0.0, sigma_px, size=pr.uv.shape) if sigma_px > 0 else pr.uv
    W, H = camera.intrinsics.width, camera.intrinsics.height
    ok = (
        pr.in_front
        & (uv[..., 0] >= margin_px - 0.5)
        & (uv[..., 0] <= W - 0.5 - margin_px)
        & (uv[..., 1] >= margin_px - 0.5)
        & (uv[..., 1] <= H - 0.5 - margin_px)
    )
    if keep < 1.0:
        ok &= rng.random(ok.shape) < keep
    f_idx, k_idx = np.nonzero(ok)
    return PixelPoints(frames[f_idx], tuple(names[k] for k in k_idx), uv[f_idx, k_idx], embodiment.name, "<synthetic>")
