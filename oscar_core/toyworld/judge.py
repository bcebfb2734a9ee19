"""A programmatic success judge for the toy pick-and-place: did the yellow ball leave its start position?

``oscar eval run MANIFEST --judge oscar_core.toyworld.judge:ball_moved`` (the
manifest from ``oscar toyworld policy-eval``). The ball is located by its
reserved colour (:mod:`oscar_core.toyworld.locate`) in every frame of the
video; its start is its position in frame 0 (else the cell's
``info.ball_start_px``), its end is its position in the last frame of the
last quarter of the video that shows it. Both pixels are mapped to the plane
of the resting ball's centre with ``info.px_to_floor_radii`` (a 3x3
homography, pixels → ball radii), so the distance is measured on the floor in
ball radii, like the simulator's outcome, whatever the camera's perspective.
Success: the distance is at least ``info.success_radii`` (3); ``partial``:
the distance as a percentage of that (capped at 100). A video whose last
quarter never shows the ball fails (partial 0): a world model that loses the
ball has not put it down elsewhere.
"""

from __future__ import annotations

import numpy as np

from .locate import OBJECT_TARGET, ColorTarget, locate

__all__ = ["ball_moved", "ball_displacement", "agreement_with_real", "BALL", "VERSION"]

VERSION = "1"
#: The ball's colour target for generated frames: at least 3 pixels (a stray yellowish pixel is not a ball).
BALL = ColorTarget("object", OBJECT_TARGET.hue, OBJECT_TARGET.hue_tol, OBJECT_TARGET.min_sat, OBJECT_TARGET.min_val,
                   min_pixels=3.0)


def _to_floor(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    p = H @ np.array([xy[0], xy[1], 1.0])
    return p[:2] / p[2]


def ball_displacement(video: np.ndarray, info: dict) -> tuple[float | None, str]:
    """How far the ball moved, ball radii on the floor, or None when it is not visible at the end; and a reason.

    video: (T, H, W, 3) uint8 RGB; info: the manifest cell's ``info`` (``px_to_floor_radii`` (3, 3),
    ``ball_start_px`` (2,) pixels).
    """
    if "px_to_floor_radii" not in info:
        raise ValueError(f"toyworld judge: clip info: expected 'px_to_floor_radii' (written by oscar toyworld "
                         f"policy-eval), found keys {sorted(info)}")
    H = np.asarray(info["px_to_floor_radii"], dtype=np.float64)
    if H.shape != (3, 3) or not np.isfinite(H).all():
        raise ValueError(f"toyworld judge: clip info: 'px_to_floor_radii': expected a finite 3x3 matrix, "
                         f"found shape {H.shape}")
    pos, _ = locate(np.asarray(video), BALL)
    T = len(pos)
    if np.isfinite(pos[0, 0]):
        start, src = pos[0], "frame 0"
    elif "ball_start_px" in info:
        start, src = np.asarray(info["ball_start_px"], dtype=np.float64), "info"
    else:
        return None, "ball not found in frame 0 and no info.ball_start_px"
    tail = range(T - 1, T - 1 - max(1, T // 4), -1)
    end_t = next((t for t in tail if np.isfinite(pos[t, 0])), None)
    if end_t is None:
        return None, f"ball not visible in the last {max(1, T // 4)} of {T} frames"
    d = float(np.linalg.norm(_to_floor(H, pos[end_t]) - _to_floor(H, start)))
    return d, (f"ball at ({pos[end_t, 0]:.1f}, {pos[end_t, 1]:.1f}) px in frame {end_t}, "
               f"{d:.2f} ball radii from its start ({start[0]:.1f}, {start[1]:.1f}) px ({src})")


def ball_moved(video: np.ndarray, clip) -> dict:
    """The judge function: ``{"binary", "partial", "reason"}`` for one rollout (module docstring).

    video: (T, H, W, 3) uint8, the whole rollout; clip: a ``JudgeClip`` whose ``info`` is the manifest cell's.
    """
    info = dict(getattr(clip, "info", None) or {})
    need = float(info.get("success_radii", 3.0))
    d, reason = ball_displacement(video, info)
    if d is None:
        return {"binary": 0, "partial": 0, "reason": reason}
    return {"binary": int(d >= need), "partial": int(min(100, round(100 * d / need))),
            "reason": f"{reason}; success needs {need:g}"}


def agreement_with_real(manifest) -> dict:
    """Run :func:`ball_moved` on every cell's ``real_video`` (the simulator's render) and compare with its
    ``real_success``: the judge's correctness check.

    manifest: path of a manifest written by ``oscar toyworld policy-eval``. Returns ``agreement`` (fraction
    of cells where the verdict equals the real outcome), ``cells``, ``disagreements`` (rows: cell, real,
    verdict, reason) and the confusion counts ``tp``, ``tn``, ``fp``, ``fn``.
    """
    from types import SimpleNamespace

    from ..evaluation.manifest import load_manifest
    from ..video import read_video

    m = load_manifest(manifest)
    counts = {"tp": 0, "tn": 0, "fp": 0, "fn": 0}
    bad = []
    n = 0
    for c in m.cells:
        if c.real_video is None or c.real_success is None:
            continue
        v = ball_moved(read_video(c.real_video), SimpleNamespace(info=c.info))
        n += 1
        key = ("t" if v["binary"] == c.real_success else "f") + ("p" if v["binary"] else "n")
        counts[key] += 1
        if v["binary"] != c.real_success:
            bad.append({"cell": c.id, "real": c.real_success, "verdict": v["binary"], "reason": v["reason"]})
    return {"cells": n, "agreement": (n - len(bad)) / n if n else float("nan"), "disagreements": bad, **counts}
