"""A small procedural hand: 21 keypoints from a few joint angles.

Used to build the bundled example, to calibrate :mod:`.flexion` and in
tests; it needs no MANO files. Bone lengths are rounded adult-hand
proportions chosen for this purpose (not measured data): metacarpals
7.5–8.5 cm, finger phalanges 1.9–4.5 cm, thumb 3–4.5 cm per bone.

Hand frame (right hand): x points from the wrist towards the fingers, y
towards the thumb side, z out of the back of the hand; fingers flex towards
-z (the palm side). The left hand is the mirror image (y negated).
"""

from __future__ import annotations

import math

import numpy as np

from .topology import FINGER_CHAINS, NUM_KEYPOINTS

__all__ = ["FIST_ANGLES", "hand_keypoints", "rotation", "place"]

# metres: wrist→MCP (metacarpal), MCP→PIP, PIP→DIP, DIP→tip
_FINGER_BONES = {
    "index": (0.085, 0.040, 0.024, 0.021),
    "middle": (0.085, 0.045, 0.028, 0.023),
    "ring": (0.080, 0.042, 0.027, 0.022),
    "pinky": (0.075, 0.033, 0.019, 0.020),
}
# angle of each metacarpal in the palm plane (radians, + towards the thumb)
_FINGER_SPREAD = {"index": 0.18, "middle": 0.05, "ring": -0.07, "pinky": -0.20}
# thumb: wrist→CMC, CMC→MCP, MCP→IP, IP→tip
_THUMB_BONES = (0.030, 0.045, 0.032, 0.028)

#: Joint flexion of a closed fist, degrees: finger MCP, PIP, DIP; thumb CMC, MCP, IP.
FIST_ANGLES = {"mcp": 90.0, "pip": 100.0, "dip": 70.0, "thumb_cmc": 25.0, "thumb_mcp": 45.0, "thumb_ip": 60.0}


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def hand_keypoints(curl: float = 0.0, thumb_curl: float | None = None, side: str = "right") -> np.ndarray:
    """(21, 3) keypoints in the hand frame, metres.

    curl: 0 = flat open hand, 1 = fist (:data:`FIST_ANGLES`), linearly in
    every joint angle; thumb_curl likewise for the thumb (default: ``curl``).
    """
    thumb_curl = curl if thumb_curl is None else thumb_curl
    kp = np.zeros((NUM_KEYPOINTS, 3))
    palm_side = np.array([0.0, 0.0, -1.0])
    angles = [math.radians(FIST_ANGLES[j]) * curl for j in ("mcp", "pip", "dip")]
    for finger, bones in _FINGER_BONES.items():
        a = _FINGER_SPREAD[finger]
        d = np.array([math.cos(a), math.sin(a), 0.0])
        chain = FINGER_CHAINS[finger]
        p = d * bones[0]
        kp[chain[0]] = p
        phi = 0.0
        for k, (length, bend) in enumerate(zip(bones[1:], angles)):
            phi += bend
            p = p + length * (math.cos(phi) * d + math.sin(phi) * palm_side)
            kp[chain[k + 1]] = p
    # the thumb leaves the wrist towards the thumb side, slightly palmar, and
    # flexes across the palm (towards the little finger and the palm side)
    d = _unit([0.85, 0.45, -0.3])
    b = _unit([-0.2, -0.6, -0.8])
    b = _unit(b - (b @ d) * d)
    chain = FINGER_CHAINS["thumb"]
    p = d * _THUMB_BONES[0]
    kp[chain[0]] = p
    phi = 0.0
    for k, (length, j) in enumerate(zip(_THUMB_BONES[1:], ("thumb_cmc", "thumb_mcp", "thumb_ip"))):
        phi += math.radians(FIST_ANGLES[j]) * thumb_curl
        p = p + length * (math.cos(phi) * d + math.sin(phi) * b)
        kp[chain[k + 1]] = p
    if side == "left":
        kp[:, 1] *= -1.0
    elif side != "right":
        raise ValueError(f"side: expected 'left' or 'right', found {side!r}")
    return kp


def rotation(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation of ``angle`` radians about ``axis`` (Rodrigues)."""
    k = _unit(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def place(kp: np.ndarray, R: np.ndarray, t) -> np.ndarray:
    """Keypoints (..., 3) in the hand frame → ``R @ p + t``."""
    return kp @ np.asarray(R, float).T + np.asarray(t, float)
