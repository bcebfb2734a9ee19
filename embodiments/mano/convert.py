"""Hand keypoints → an oscar trajectory; cameras for egocentric data.

Frames. The renderer projects ``keypoints`` through the camera file exactly
as it projects a robot's points, so the points must be in the frame the
camera's extrinsic refers to. Two cases cover hand data:

* egocentric data whose keypoints are already in the camera frame (OpenCV
  axes: x right, y down, z forward): pass them as they are and render with
  :func:`egocentric_camera` (identity extrinsic, the dataset's intrinsics);
* world-frame keypoints with a moving (head-mounted) camera: pass the
  per-frame camera poses ``camera_poses`` (T, 4, 4), camera-to-world, with
  their axis convention (``"opencv"``, or ``"opengl"`` for x right, y up,
  looking along -z as ARKit and OpenGL use; any name of
  :data:`oscar_core.camera.CONVENTIONS`). The converter moves every point
  into the OpenCV camera frame of its own frame, so the stored trajectory is
  again camera-frame and the same identity-extrinsic camera renders it.

A static third-person camera needs neither: keep world-frame keypoints and
give the camera's real extrinsic in the camera file.
"""

from __future__ import annotations

import numpy as np

from oscar_core import Camera, Intrinsics, Trajectory
from oscar_core.camera import convention_to_opencv

from .flexion import hand_openness, hold_missing
from .topology import HANDS, NUM_KEYPOINTS

__all__ = ["trajectory_from_keypoints", "to_camera_frame", "egocentric_camera", "gripper_signal"]


def _check_poses(poses, T: int) -> np.ndarray:
    P = np.asarray(poses, dtype=np.float64)
    if P.shape != (T, 4, 4):
        raise ValueError(f"camera_poses: expected shape ({T}, 4, 4) (camera-to-world per frame), found {P.shape}")
    if not np.isfinite(P).all():
        t = int(np.argwhere(~np.isfinite(P))[0, 0])
        raise ValueError(f"camera_poses: expected finite values, found non-finite entries at frame {t}")
    R = P[:, :3, :3]
    dev = np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
    bottom = np.abs(P[:, 3] - [0, 0, 0, 1]).max(axis=1)
    det = np.linalg.det(R)
    bad = (dev > 1e-5) | (bottom > 1e-9) | (det < 0)
    if bad.any():
        t = int(np.argmax(bad))
        raise ValueError(
            f"camera_poses: expected rigid transforms (orthonormal rotation, det +1, last row 0 0 0 1), "
            f"found rotation error {dev[t]:.2g}, det {det[t]:.3g}, last row {P[t, 3].tolist()} at frame {t}"
        )
    return P


def to_camera_frame(points, camera_poses, convention: str = "opencv") -> np.ndarray:
    """World points (T, ..., 3) → the OpenCV camera frame of each frame's camera.

    camera_poses: (T, 4, 4) camera-to-world, camera axes in ``convention``.
    NaN points stay NaN.
    """
    pts = np.asarray(points, dtype=np.float64)
    T = pts.shape[0]
    P = _check_poses(camera_poses, T)
    R, t = P[:, :3, :3], P[:, :3, 3]
    C = convention_to_opencv(convention)[:3, :3]  # p_cv = C @ p_conv
    flat = pts.reshape(T, -1, 3)
    with np.errstate(invalid="ignore"):
        local = np.einsum("tji,tnj->tni", R, flat - t[:, None, :])  # R^T (p - t)
        out = local @ C.T
    return out.reshape(pts.shape)


def gripper_signal(keypoints) -> np.ndarray:
    """(T, 2, 21, 3) → (T, 2) finite openness per hand: :func:`.flexion.hand_openness`
    with frames where a hand is missing holding its last value (:func:`.flexion.hold_missing`)."""
    return hold_missing(hand_openness(keypoints))


def _as_two_hands(keypoints, hand: str | None) -> np.ndarray:
    kp = np.asarray(keypoints, dtype=np.float64)
    if kp.ndim == 3 and kp.shape[1:] == (NUM_KEYPOINTS, 3):
        if hand not in HANDS:
            raise ValueError(
                f"keypoints of shape {kp.shape} hold one hand: pass hand='left' or hand='right', found {hand!r}"
            )
        both = np.full((kp.shape[0], 2, NUM_KEYPOINTS, 3), np.nan)
        both[:, HANDS.index(hand)] = kp
        return both
    if kp.ndim != 4 or kp.shape[1:] != (2, NUM_KEYPOINTS, 3):
        raise ValueError(
            f"keypoints: expected shape (T, 2, {NUM_KEYPOINTS}, 3) (hand axis 0 = left, 1 = right) "
            f"or (T, {NUM_KEYPOINTS}, 3) with hand=..., found {kp.shape}"
        )
    if hand is not None:
        raise ValueError("hand=... is only for keypoints of a single hand, shape (T, 21, 3)")
    return kp


def trajectory_from_keypoints(
    keypoints,
    fps: float,
    *,
    hand: str | None = None,
    camera_poses=None,
    camera_convention: str = "opencv",
    gripper=None,
    timestamps=None,
    source: str = "<keypoints>",
) -> Trajectory:
    """A ``mano`` trajectory from 3D hand keypoints.

    keypoints: (T, 2, 21, 3) metres, hand axis 0 = left, 1 = right, keypoint
        order of :data:`.topology.KEYPOINT_NAMES`; NaN marks a missing point or
        hand. Or (T, 21, 3) for one hand with ``hand="left"``/``"right"``.
    camera_poses: optional (T, 4, 4) camera-to-world poses in
        ``camera_convention`` axes: the keypoints are then world-frame and are
        moved into each frame's camera frame (see the module docstring).
    gripper: optional (T, 2) open/close signal in [0, 1] (1 = open) to use
        instead of the one computed from the keypoints (:func:`gripper_signal`).
    """
    kp = _as_two_hands(keypoints, hand)
    if np.isinf(kp).any():
        t = int(np.argwhere(np.isinf(kp))[0, 0])
        raise ValueError(f"keypoints: expected finite values or NaN (missing), found inf at frame {t}")
    if camera_poses is not None:
        kp = to_camera_frame(kp, camera_poses, camera_convention)
    T = kp.shape[0]
    g = gripper_signal(kp) if gripper is None else np.asarray(gripper, dtype=np.float64)
    return Trajectory(
        joint_names=(),
        q=np.zeros((T, 0)),
        fps=fps,
        gripper=g,
        gripper_names=HANDS,
        timestamps=timestamps,
        source=source,
        keypoints=kp.reshape(T, 2 * NUM_KEYPOINTS, 3),
    )


def egocentric_camera(fx: float, fy: float, cx: float, cy: float, width: int, height: int, distortion=()) -> Camera:
    """The camera of camera-frame keypoints: the dataset's intrinsics (pixels),
    identity extrinsic, OpenCV axes, static; tagged for the ``mano`` embodiment."""
    return Camera(Intrinsics(fx, fy, cx, cy, width, height, tuple(distortion)), np.eye(4), embodiment="mano")
