"""A programmatic success judge for the toy pick-and-place: did the yellow ball leave its start and lie elsewhere?

``oscar eval run MANIFEST --judge oscar_core.toyworld.judge:ball_moved`` (the
manifest from ``oscar toyworld policy-eval``). The ball's pixels are found by
their reserved colour (:mod:`oscar_core.toyworld.locate`, ≥ 3 pixels) and
split into 8-connected blobs. Distances are measured on the floor in ball
radii: pixels are mapped to the plane of the resting ball's centre with
``info.px_to_floor_radii`` (a 3x3 homography, pixels → ball radii), like the
simulator's outcome, whatever the camera's perspective.

**Start**: the frame-0 blob nearest ``info.ball_start_px`` (else the largest);
its centroid and pixel count ``n0``. **Tail**: the last ``max(3, T // 4)``
frames (4 of 17). A success needs all three, each a median over the tail so
one smeared or blank generated frame decides nothing:

1. **the ball left its start** — the yellow pixels within 1.5 ball radii
   (pixels, ``info.ball_radius_px``, else from ``n0``) of the start are at
   most :data:`LEFT_FRACTION` of frame 0's (a ball left at its start, or
   duplicated, is not a move);
2. **it is found as a ball** — the largest blob of the frame is *compact*: at
   most :data:`MAX_AREA_RATIO` times and at least :data:`MIN_AREA_RATIO` of
   the area the ball would have there (π ``info.ball_radius_px``², else frame
   0's blob, scaled by the homography's local area ratio between the start and
   the blob) and filling at least
   :data:`MIN_FILL` of the disc its farthest pixel spans (a yellow smear or a
   streak along the arm is not a ball) — in the last frame (``oscar toyworld
   policy-eval`` re-draws a session until every episode's last frame shows at
   least half the ball; earlier tail frames may hide it under the gripper);
3. **far enough** — the median floor distance of that blob from the start,
   over the tail frames that show a compact ball, is at least
   ``info.success_radii`` (3).

``partial`` = the median distance of the compact blob as a percentage of
``success_radii`` (capped at 100; 0 where no compact blob is found or the
ball did not leave its start). The reason names every number. Real renders (the simulator's) must keep 100 %
agreement: :func:`agreement_with_real`. :func:`ball_reading` returns the
per-frame internals (the diagnosis in docs/evaluation.md reads them).

Version 1 (before 2026-11-25) took the centroid of all yellow pixels in the
last frame showing any: generated smears moved that centroid 3–11 radii where
the ball stayed. Version 2 (same day) needed the compact ball in half the tail
frames, which failed one real render in 120 (the ball under the gripper in 3
of the last 4 frames). Version 4 (2026-11-29) gives a ball that did not leave
its start partial 0 (version 3 gave a copy of it far away partial 100) and a
reason that says the far blob is a copy; every binary verdict is unchanged.
Version 5 (2026-11-30) takes the ball's expected area from ``info.ball_radius_px``
(π r²) where info has it, no longer from frame 0's blob: in 2 of the 9 quick
action-following sets the arm hides over half the ball in frame 0 (8 px of 16
and of 22), and the toy VAE's reconstruction of that frame keeps 3, so a ball
carried whole read as "not ball-like" (23 px against 4 expected). The quick
sets (seed 0) are byte-identical under both versions.
"""

from __future__ import annotations

import numpy as np

from .locate import OBJECT_TARGET, ColorTarget, color_mask

__all__ = [
    "BALL",
    "LEFT_FRACTION",
    "MAX_AREA_RATIO",
    "MIN_AREA_RATIO",
    "MIN_FILL",
    "START_DISK_RADII",
    "VERSION",
    "agreement_with_real",
    "ball_displacement",
    "ball_moved",
    "ball_reading",
]

VERSION = "5"
#: The ball's colour target for generated frames: at least 3 pixels (a stray yellowish pixel is not a ball).
BALL = ColorTarget(
    "object", OBJECT_TARGET.hue, OBJECT_TARGET.hue_tol, OBJECT_TARGET.min_sat, OBJECT_TARGET.min_val, min_pixels=3.0
)
#: The start disk's radius, ball radii (pixels of the ball's start radius).
START_DISK_RADII = 1.5
#: The ball left its start when the median tail count in the start disk is at most this fraction of frame 0's.
LEFT_FRACTION = 0.25
#: A blob is the ball when its area is within [MIN_AREA_RATIO, MAX_AREA_RATIO] x the ball's expected area there...
MAX_AREA_RATIO = 2.5
MIN_AREA_RATIO = 0.2
#: ... and its pixels fill at least this fraction of the disc (centroid, farthest pixel).
MIN_FILL = 0.3


def _to_floor(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    p = H @ np.array([xy[0], xy[1], 1.0])
    return p[:2] / p[2]


def _floor_area_per_px(H: np.ndarray, xy: np.ndarray) -> float:
    """|det| of the Jacobian of the pixel → floor map at ``xy`` (floor radii² per pixel²)."""
    e = 0.5
    dx = (_to_floor(H, xy + [e, 0]) - _to_floor(H, xy - [e, 0])) / (2 * e)
    dy = (_to_floor(H, xy + [0, e]) - _to_floor(H, xy - [0, e])) / (2 * e)
    return abs(float(dx[0] * dy[1] - dx[1] * dy[0]))


def _blobs(mask: np.ndarray, min_pixels: float) -> list[dict]:
    """8-connected blobs of a (H, W) bool mask with at least ``min_pixels`` pixels, largest first:
    ``n`` pixels, ``c`` (2,) centroid (x, y) pixels, ``reach`` farthest pixel's distance from the centroid."""
    from scipy import ndimage

    lab, k = ndimage.label(mask, structure=np.ones((3, 3), bool))
    out = []
    for j in range(1, k + 1):
        ys, xs = np.nonzero(lab == j)
        if len(xs) < min_pixels:
            continue
        c = np.array([xs.mean(), ys.mean()])
        out.append({"n": len(xs), "c": c, "reach": float(np.hypot(xs - c[0], ys - c[1]).max())})
    return sorted(out, key=lambda b: -b["n"])


def _check_info(info: dict) -> np.ndarray:
    if "px_to_floor_radii" not in info:
        raise ValueError(
            f"toyworld judge: clip info: expected 'px_to_floor_radii' (written by oscar toyworld "
            f"policy-eval), found keys {sorted(info)}"
        )
    H = np.asarray(info["px_to_floor_radii"], dtype=np.float64)
    if H.shape != (3, 3) or not np.isfinite(H).all():
        raise ValueError(
            f"toyworld judge: clip info: 'px_to_floor_radii': expected a finite 3x3 matrix, found shape {H.shape}"
        )
    return H


def ball_reading(video: np.ndarray, info: dict) -> dict:
    """What the judge sees in one video (module docstring): the start, and per tail frame the pixels left at the
    start and the largest blob.

    video: (T, H, W, 3) uint8 RGB; info: the manifest cell's ``info``. Returns ``start_px`` (2,) or None,
    ``start_src``, ``n0`` (frame 0's pixels in the start disk), ``r_px``, ``tail`` (frame indices),
    ``at_start`` (per tail frame), ``blob`` (per tail frame: None or ``{"px", "n", "expected_n", "fill",
    "compact", "radii"}``), ``left`` (bool), ``found`` (tail frames with a compact blob), ``last_found`` (the last frame has one), ``distance`` (median
    radii over those frames, or None) and ``reason`` (why no start, where applicable).
    """
    H = _check_info(info)
    video = np.asarray(video)
    if video.ndim != 4 or video.shape[-1] != 3 or len(video) < 2:
        raise ValueError(f"toyworld judge: video: expected (T >= 2, H, W, 3) RGB, found shape {video.shape}")
    mask = color_mask(video, BALL)
    T, h, w = mask.shape
    first = _blobs(mask[0], BALL.min_pixels)
    hint = np.asarray(info["ball_start_px"], dtype=np.float64) if "ball_start_px" in info else None
    if first:
        b0 = min(first, key=lambda b: np.linalg.norm(b["c"] - hint)) if hint is not None else first[0]
        start, src = b0["c"], "frame 0"
    elif hint is not None:
        start, src = hint, "info"
    else:
        return {"start_px": None, "reason": "ball not found in frame 0 and no info.ball_start_px"}
    ys, xs = np.mgrid[0:h, 0:w]
    if "ball_radius_px" in info:
        r_px = float(info["ball_radius_px"])
    elif first:
        r_px = float(np.sqrt(b0["n"] / np.pi))
    else:
        return {"start_px": None, "reason": "ball not found in frame 0 and no info.ball_radius_px"}
    disk = np.hypot(xs - start[0], ys - start[1]) <= START_DISK_RADII * r_px
    n0 = int((mask[0] & disk).sum()) if first else round(np.pi * r_px**2)
    # the ball's unoccluded area at its start: the scene's radius where info has it (version 5), since frame 0's blob
    # is partly hidden under the arm in some scenes and a generated or decoded first frame may shrink it
    n_ball = np.pi * r_px**2 if "ball_radius_px" in info or not first else b0["n"]
    a0 = _floor_area_per_px(H, start)
    s_floor = _to_floor(H, start)
    tail = list(range(T - max(3, T // 4), T)) if T > 3 else list(range(1, T))
    at_start, blobs, dists = [], [], []
    for t in tail:
        at_start.append(int((mask[t] & disk).sum()))
        bs = _blobs(mask[t], BALL.min_pixels)
        if not bs:
            blobs.append(None)
            continue
        b = bs[0]
        expected = n_ball * a0 / max(_floor_area_per_px(H, b["c"]), 1e-12)
        fill = b["n"] / (np.pi * max(b["reach"], 0.5) ** 2)
        compact = bool(MIN_AREA_RATIO * expected <= b["n"] <= MAX_AREA_RATIO * expected and fill >= MIN_FILL)
        d = float(np.linalg.norm(_to_floor(H, b["c"]) - s_floor))
        blobs.append(
            {
                "px": [round(float(v), 2) for v in b["c"]],
                "n": b["n"],
                "expected_n": round(expected, 1),
                "fill": round(float(fill), 3),
                "compact": compact,
                "radii": round(d, 3),
            }
        )
        if compact:
            dists.append(d)
    left = bool(np.median(at_start) <= LEFT_FRACTION * n0)
    return {
        "start_px": [round(float(v), 2) for v in start],
        "start_src": src,
        "n0": n0,
        "r_px": round(r_px, 3),
        "tail": tail,
        "at_start": at_start,
        "blob": blobs,
        "left": left,
        "found": len(dists),
        "last_found": bool(blobs[-1] is not None and blobs[-1]["compact"]),
        "distance": float(np.median(dists)) if dists else None,
    }


def ball_displacement(video: np.ndarray, info: dict) -> tuple[float | None, str]:
    """The median distance (ball radii on the floor) of the compact ball blob in the tail from the start, or None
    when the last frame shows none; and a reason. (Ignores whether the ball also stayed at its start:
    :func:`ball_moved` checks that.)"""
    r = ball_reading(video, info)
    if r["start_px"] is None:
        return None, r["reason"]
    k = len(r["tail"])
    if not r["last_found"]:
        return None, "no compact ball blob in the last frame"
    return r["distance"], (
        f"compact ball blob in {r['found']} of the last {k} frames, median {r['distance']:.2f} "
        f"ball radii from its start ({r['start_px'][0]:.1f}, {r['start_px'][1]:.1f}) px "
        f"({r['start_src']})"
    )


def ball_moved(video: np.ndarray, clip) -> dict:
    """The judge function: ``{"binary", "partial", "reason"}`` for one rollout (module docstring).

    video: (T, H, W, 3) uint8, the whole rollout; clip: a ``JudgeClip`` whose ``info`` is the manifest cell's.
    """
    info = dict(getattr(clip, "info", None) or {})
    need = float(info.get("success_radii", 3.0))
    r = ball_reading(video, info)
    if r["start_px"] is None:
        return {"binary": 0, "partial": 0, "reason": r["reason"]}
    k = len(r["tail"])
    stay = (
        f"{int(np.median(r['at_start']))} yellow pixels (median of the last {k} frames) left in the start "
        f"disk against {r['n0']} in frame 0"
    )
    if not r["last_found"]:
        b = r["blob"][-1]
        why = (
            f"its largest yellow blob is not ball-like ({b['n']} px where a ball has {b['expected_n']:.0f}, "
            f"fill {b['fill']:.2f})"
            if b is not None
            else "no yellow blob"
        )
        return {"binary": 0, "partial": 0, "reason": f"no compact ball in the last frame: {why}; {stay}"}
    d = r["distance"]
    if not r["left"]:
        # the ball is still at its start: a compact blob elsewhere is a second ball, not this one carried there
        blob = (
            f"the compact yellow blob {d:.2f} ball radii away is a copy, not the ball moved"
            if d > START_DISK_RADII
            else f"the compact ball blob lies {d:.2f} ball radii from its start"
        )
        return {
            "binary": 0,
            "partial": 0,
            "reason": f"the ball did not leave its start: {stay} (a move leaves at most {LEFT_FRACTION:.0%}); {blob}",
        }
    partial = int(min(100, round(100 * d / need)))
    where = f"compact ball blob {d:.2f} ball radii (median) from its start; {stay}; success needs {need:g}"
    return {"binary": int(d >= need), "partial": partial, "reason": where}


ball_moved.version = VERSION  # oscar eval run's --judge module:attr keys stored verdicts on it


def agreement_with_real(manifest) -> dict:
    """Run :func:`ball_moved` on every cell's ``real_video`` (the simulator's render) and compare with its
    ``real_success``: the judge's correctness check.

    manifest: path of a manifest written by ``oscar toyworld policy-eval``. Returns ``agreement`` (fraction
    of cells where the verdict equals the real outcome), ``cells``, ``disagreements`` (rows: cell, real,
    verdict, reason) and the confusion counts ``tp``, ``tn``, ``fp``, ``fn``.
    """
    from types import SimpleNamespace

    from ..evaluation.manifest import load_manifest
    from ..media.video import read_video

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
