"""The hand's open/close signal: normalised fingertip flexion, as openness.

For the four fingers f (index, middle, ring, pinky) with keypoints wrist w,
MCP m, PIP p, DIP d and tip t::

    r_f = |t - w| / (|m - w| + |p - m| + |d - p| + |t - d|)

is 1 when the finger and its metacarpal are straight and in line (the chain
is fully stretched) and shrinks as the finger curls towards the palm. The
hand's value is the mean over the fingers that are present, and

    openness = clip((r - R_FIST) / (R_OPEN - R_FIST), 0, 1)

with ``R_OPEN = 1`` (flat hand, by construction) and ``R_FIST = 0.333``,
the value of a closed fist: :func:`.synthetic.hand_keypoints` with curl 1
(MCP 90°, PIP 100°, DIP 70°) gives r = 0.3329. So a flat open hand is 1, a
fist is 0, a half-closed power grasp about 0.4–0.6. As the hand closes, r
falls monotonically until the last few degrees before a full fist, where the
tips slide past their closest point to the wrist (r bottoms out at 0.3305);
that stretch is below ``R_FIST`` and reads 0. The ratio only uses
distances along one hand, so it does not depend on the hand's position,
orientation or size (metres or any other unit). The thumb is left out: its
opposition moves the tip sideways more than it shortens the chain.

This is the paper's "normalised fingertip flexion for humans": the signal
whose open/close crossings bias the start of training windows, as gripper
openness does for robots (1 = open, 0 = closed in both). It is also the
``gripper`` signal (range 0–1, low = closed) that draws the indicator.
"""

from __future__ import annotations

import numpy as np

from .topology import FINGER_CHAINS, NUM_KEYPOINTS

__all__ = ["R_OPEN", "R_FIST", "chain_ratio", "hand_openness", "hold_missing"]

R_OPEN = 1.0
R_FIST = 0.333
_FINGERS = ("index", "middle", "ring", "pinky")


def chain_ratio(keypoints) -> np.ndarray:
    """(..., 21, 3) keypoints of one hand → (...) mean straightness ratio r (NaN if no finger is complete)."""
    kp = np.asarray(keypoints, dtype=np.float64)
    if kp.shape[-2:] != (NUM_KEYPOINTS, 3):
        raise ValueError(f"hand keypoints: expected shape (..., {NUM_KEYPOINTS}, 3), found {kp.shape}")
    ratios = []
    with np.errstate(invalid="ignore", divide="ignore"):
        for f in _FINGERS:
            chain = kp[..., (0,) + FINGER_CHAINS[f], :]  # (..., 5, 3)
            length = np.linalg.norm(np.diff(chain, axis=-2), axis=-1).sum(-1)
            reach = np.linalg.norm(chain[..., -1, :] - chain[..., 0, :], axis=-1)
            ratios.append(np.where(length > 0, reach / length, np.nan))
    r = np.stack(ratios, axis=-1)
    present = np.isfinite(r)
    total = np.where(present, r, 0.0).sum(-1)
    count = present.sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def hand_openness(keypoints) -> np.ndarray:
    """(..., 21, 3) keypoints of one hand → (...) openness in [0, 1]: 1 = flat open hand, 0 = fist.

    NaN where the hand (or every finger of it) is missing. For both hands of
    a keypoint array ``(T, 2, 21, 3)`` the result is ``(T, 2)``.
    """
    r = chain_ratio(keypoints)
    with np.errstate(invalid="ignore"):
        return np.clip((r - R_FIST) / (R_OPEN - R_FIST), 0.0, 1.0)


def hold_missing(signal, default: float = 1.0) -> np.ndarray:
    """(T, G) signal with NaN gaps → finite: each gap takes the last value before
    it (leading gaps the first value after it); a column with no value at all
    takes ``default`` (1 = open). Holding, rather than interpolating, adds no
    open/close crossing that was not observed."""
    s = np.array(signal, dtype=np.float64)
    if s.ndim == 1:
        s = s[:, None]
    T = s.shape[0]
    for g in range(s.shape[1]):
        col = s[:, g]
        ok = np.isfinite(col)
        if not ok.any():
            col[:] = default
            continue
        idx = np.where(ok, np.arange(T), -1)
        idx = np.maximum.accumulate(idx)
        idx[idx < 0] = np.argmax(ok)
        s[:, g] = col[idx]
    return s
