"""What the toy world's scores measure per frame, shared by the whole-clip table (``evaluate``) and the per-chunk
split (``per_chunk``): the metric names, their constants and the changed-pixel mask of motion IoU."""

from __future__ import annotations

import numpy as np

__all__ = [
    "METRICS",
    "PSNR_CAP",
    "MOTION_THRESHOLD",
    "MOVED_OBJECT_SHIFT_PX",
    "motion_mask",
    "mask_iou",
    "moved_frames",
    "frame_series",
]

PSNR_CAP = 100.0
METRICS = ("psnr_db", "ssim", "motion_iou", "ee_error_px", "object_error_px", "moved_object_error_px")
#: a pixel "moved" at frame t when its grey level differs from frame 0's by more than this (0-255 scale)
MOTION_THRESHOLD = 24.0
#: the true ball "has moved" at frame t when its centroid is more than this from frame 0's (pixels; about one
#: ball radius at 64 x 64)
MOVED_OBJECT_SHIFT_PX = 3.0


def motion_mask(video: np.ndarray, threshold: float = MOTION_THRESHOLD) -> np.ndarray:
    """(T − 1, H, W) bool: pixels whose grey level (mean of RGB) changed from frame 0 by more than ``threshold``.

    video: (T, H, W, 3), uint8 (or any integer type) or float, 0-255. The rule is applied exactly, as
    |ΔR + ΔG + ΔB| > 3 · threshold: in integers for integer frames, in float64 otherwise (a float32 mean
    rounds, and would count some changes of exactly ``threshold`` levels whose sums are not multiples of 3).
    """
    v = np.asarray(video)
    s = v.astype(np.int64 if np.issubdtype(v.dtype, np.integer) else np.float64).sum(-1)
    return np.abs(s[1:] - s[:1]) > 3 * threshold


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two bool masks of one shape, pooled over every element; NaN when both are empty."""
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else float("nan")


def moved_frames(gt_px: np.ndarray, min_shift: float = MOVED_OBJECT_SHIFT_PX) -> np.ndarray:
    """(T,) bool: frames where the true object's centroid is more than ``min_shift`` pixels from frame 0's.

    gt_px: (T, 2) centroids in pixels, NaN where the object is not shown (False there, and everywhere when
    frame 0 does not show it)."""
    with np.errstate(invalid="ignore"):
        return np.linalg.norm(gt_px - gt_px[0], axis=1) > min_shift


def frame_series(pred: np.ndarray, gt: np.ndarray) -> dict:
    """What every toy-world score is a mean of, computed once per clip: pred, gt (T, H, W, 3) uint8.

    Returns ``psnr`` (T,) dB capped at :data:`PSNR_CAP`, ``ssim`` (T,), ``motion_pred`` / ``motion_gt``
    (T − 1, H, W) bool (:func:`motion_mask`: row t − 1 is frame t), and ``ee`` / ``object``: the results of
    :func:`oscar_core.toyworld.locate.position_errors` for the end-effector marker and the object."""
    from ..metrics import psnr, ssim
    from .locate import EE_TARGET, OBJECT_TARGET, position_errors

    return {
        "psnr": np.minimum(psnr(pred, gt, n_frames=None), PSNR_CAP),
        "ssim": ssim(pred, gt, n_frames=None),
        "motion_pred": motion_mask(pred),
        "motion_gt": motion_mask(gt),
        "ee": position_errors(pred, gt, EE_TARGET),
        "object": position_errors(pred, gt, OBJECT_TARGET),
    }
