"""Find the end-effector marker and the object in RGB frames by their reserved colours.

A pixel belongs to a target when its hue is within ``hue_tol`` degrees of the
target's hue (:data:`~oscar_core.toyworld.scene.EE_HUE`,
:data:`~oscar_core.toyworld.scene.OBJECT_HUE`), its saturation is at least
``min_sat`` and its value at least ``min_val`` (HSV, both in [0, 1]). The
target's position is the centroid of its pixels (x, y in pixels, pixel
centres at integer coordinates); a frame with fewer than ``min_pixels`` such
pixels has no detection (NaN). Links, floor and backdrop never carry these
hues at that saturation (:mod:`oscar_core.toyworld.scene`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import EE_HUE, OBJECT_HUE

__all__ = [
    "ColorTarget",
    "EE_TARGET",
    "OBJECT_TARGET",
    "BALL_TARGET",
    "ball_position",
    "ball_mask",
    "color_mask",
    "locate",
    "position_errors",
]


@dataclass(frozen=True)
class ColorTarget:
    """hue: degrees; hue_tol: degrees; min_sat, min_val: in [0, 1]; min_pixels: pixels."""

    name: str
    hue: float
    hue_tol: float = 18.0
    min_sat: float = 0.5
    min_val: float = 0.2
    min_pixels: float = 1.0


EE_TARGET = ColorTarget("end_effector", EE_HUE)
OBJECT_TARGET = ColorTarget("object", OBJECT_HUE)
#: The ball in generated frames: at least 3 pixels of its colour (the judge's rule: a stray pixel is not a ball).
BALL_TARGET = ColorTarget("object", OBJECT_HUE, min_pixels=3.0)


def color_mask(frames: np.ndarray, target: ColorTarget) -> np.ndarray:
    """frames: (T, H, W, 3) or (H, W, 3) uint8 RGB → bool mask of the same leading shape."""
    x = np.asarray(frames, dtype=np.float32) / 255.0
    mx, mn = x.max(-1), x.min(-1)
    delta = mx - mn
    r, g, b = x[..., 0], x[..., 1], x[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(mx == r, ((g - b) / delta) % 6, np.where(mx == g, (b - r) / delta + 2, (r - g) / delta + 4)) * 60.0
        s = np.where(mx > 0, delta / mx, 0.0)
    dh = np.abs((h - target.hue + 180.0) % 360.0 - 180.0)
    return (delta > 0) & (dh <= target.hue_tol) & (s >= target.min_sat) & (mx >= target.min_val)


def locate(frames: np.ndarray, target: ColorTarget) -> tuple[np.ndarray, np.ndarray]:
    """Centroid of ``target``'s pixels in each frame.

    frames: (T, H, W, 3) uint8 RGB. Returns positions (T, 2) pixels (x, y;
    NaN where not found) and pixel counts (T,).
    """
    m = color_mask(frames, target)
    T, H, W = m.shape
    ys, xs = np.mgrid[0:H, 0:W]
    n = m.sum(axis=(1, 2)).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        cx = (m * xs).sum(axis=(1, 2)) / n
        cy = (m * ys).sum(axis=(1, 2)) / n
    pos = np.stack([cx, cy], axis=1)
    pos[n < target.min_pixels] = np.nan
    return pos, n


def ball_position(frames: np.ndarray) -> np.ndarray:
    """(T, 2) pixels: the centroid of the ball's colour in each of ``frames`` (T, H, W, 3) uint8, NaN where fewer
    than 3 pixels show it (:data:`BALL_TARGET`); the locator of ``oscar eval action-following``'s toy sets."""
    return locate(frames, BALL_TARGET)[0]


def ball_mask(frames: np.ndarray) -> np.ndarray:
    """(T, H, W) bool: the pixels of the ball's reserved colour in ``frames`` (T, H, W, 3) uint8 RGB; the toy
    world's focus mask for training (``data.focus_mask: oscar_core.toyworld.locate:ball_mask``,
    :mod:`oscar_core.train.focus`)."""
    return color_mask(frames, OBJECT_TARGET)


def position_errors(pred: np.ndarray, gt: np.ndarray, target: ColorTarget) -> dict:
    """Localisation error of ``target`` in predicted frames against ground-truth frames.

    pred, gt: (T, H, W, 3) uint8. Error per frame = Euclidean distance (pixels)
    between the centroids, over frames where the ground truth shows the
    target. A frame where the prediction lacks it counts as a miss and is
    scored with the image diagonal (so losing the object is never better than
    misplacing it). Returns ``error_px`` (mean), ``median_px``, ``found``
    (fraction of frames with a detection in the prediction), ``frames``
    (frames counted), ``per_frame`` (T,) errors (NaN where not counted) and
    ``gt_px`` (T, 2) the ground truth's centroids (NaN where not shown).
    """
    pp, _ = locate(pred, target)
    gp, _ = locate(gt, target)
    H, W = gt.shape[1:3]
    diag = float(np.hypot(H, W))
    shown = np.isfinite(gp[:, 0])
    found = np.isfinite(pp[:, 0])
    err = np.full(len(gt), np.nan)
    both = shown & found
    err[both] = np.linalg.norm(pp[both] - gp[both], axis=1)
    err[shown & ~found] = diag
    n = int(shown.sum())
    return {
        "error_px": float(np.nanmean(err)) if n else float("nan"),
        "median_px": float(np.nanmedian(err)) if n else float("nan"),
        "found": float(found[shown].mean()) if n else float("nan"),
        "frames": n,
        "per_frame": err,
        "gt_px": gp,
    }
