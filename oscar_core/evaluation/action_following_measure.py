"""What one variant's video measures against its true frames, for the action-following benchmark
(:mod:`.action_following`): per chunk, PSNR and the object's distance from its true place; at the end, that
distance in the last frame. Distances are in ball radii where the set's ``info`` gives ``ball_radius_px``."""

from __future__ import annotations

import numpy as np

__all__ = ["distance_unit", "score_variant"]


def distance_unit(info: dict) -> tuple[float, str]:
    """``(pixels per unit, unit name)``: ball radii where ``info.ball_radius_px`` is a positive number, else pixels."""
    r = info.get("ball_radius_px")
    if isinstance(r, (int, float)) and not isinstance(r, bool) and r > 0:
        return float(r), "ball radii"
    return 1.0, "px"


def _object_errors(pred_px: np.ndarray, true_px: np.ndarray, diag: float) -> np.ndarray:
    """(T,) error per frame in pixels: NaN where the truth shows no object, ``diag`` where the model shows none."""
    shown = np.isfinite(true_px[:, 0])
    found = np.isfinite(pred_px[:, 0])
    err = np.full(len(true_px), np.nan)
    both = shown & found
    err[both] = np.linalg.norm(pred_px[both] - true_px[both], axis=1)
    err[shown & ~found] = diag
    return err


def _finite_or_none(x):
    return None if x is None or not np.isfinite(x) else round(float(x), 4)


def score_variant(video: np.ndarray, truth: np.ndarray | None, locator, info: dict, chunk: int) -> dict:
    """The truth-dependent numbers of one variant's video (T, H, W, 3) uint8 against its true frames ``truth`` (or
    None): ``end_error`` (object, last frame), ``end_note`` (why it is None) and ``chunks`` (per chunk of ``chunk``
    new frames: ``psnr_db``, ``object_error``), distances in :func:`distance_unit`'s unit."""
    from ..metrics.video import psnr

    if truth is None:
        return {"end_error": None, "end_note": "no true frames", "chunks": []}
    scale, _ = distance_unit(info)
    T, H, W = truth.shape[:3]
    p = np.minimum(psnr(video, truth, n_frames=None), 100.0)
    err = None
    note = "no locator"
    if locator is not None:
        pp = np.asarray(locator(video), dtype=np.float64)
        tp = np.asarray(locator(truth), dtype=np.float64)
        err = _object_errors(pp, tp, float(np.hypot(H, W))) / scale
        if not np.isfinite(tp[-1, 0]):
            note = "the true last frame shows no object"
        elif not np.isfinite(pp[-1, 0]):
            note = "the model's last frame shows no object"
        else:
            note = None
    chunks = []
    for k in range(1, (T - 1) // chunk + 1):
        lo, hi = 1 + chunk * (k - 1), chunk * k + 1
        oe = err[lo:hi] if err is not None else np.array([np.nan])
        chunks.append(
            {
                "psnr_db": round(float(np.mean(p[lo:hi])), 4),
                "object_error": _finite_or_none(np.nanmean(oe) if np.isfinite(oe).any() else np.nan),
            }
        )
    end = None if note is not None else _finite_or_none(err[-1])
    return {"end_error": end, "end_note": note, "chunks": chunks}
