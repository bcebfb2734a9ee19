"""What the toy world's scores measure per frame, shared by the whole-clip table (``evaluate``) and the per-chunk
split (``per_chunk``): the metric names, their constants and the changed-pixel mask of motion IoU."""

from __future__ import annotations

import numpy as np

__all__ = ["METRICS", "PSNR_CAP", "MOTION_THRESHOLD", "MOVED_OBJECT_SHIFT_PX", "motion_mask"]

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
