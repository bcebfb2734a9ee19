"""The calibration score: how well the robot rendered through a camera lines up with the video, in [0, 1].

No network weights: the score compares *where the video changes* with *where
the rendered robot moves*, on pairs of frames ``gap`` frames apart where the
robot moves.

For a pair of frames (t, t + gap), both resized to a working width of
``width`` pixels, a pixel *moves* when one of its R, G, B values (0–255)
changes between the two frames by more than ``threshold``:

- the video's motion mask ``A``: the pixels that move in the video;
- the rendered motion mask ``B``: the pixels that move in the robot's body
  rendered through the camera on black. The body is the capsule condition
  (:mod:`oscar_core.render.capsules`: shaded capsules along the skeleton's
  edges, two fingers per gripper) for embodiments with a kinematic tree; for
  the others (hands given as keypoints), the skeleton video, whose thin motion
  mask is thickened by ``skeleton_dilate_px`` pixels;
- the pair's value: intersection over union ``|A ∧ B| / |A ∨ B|`` (0 when
  both are empty).

A pair counts where the robot moves: some skeleton point travels at least
``min_travel_m`` metres (3D, forward kinematics) between its two frames, so a
camera that shows no robot at all is scored 0, not skipped. The score is the
median of the counted pairs' values (NaN when the robot never moves);
``per_pair`` keeps every pair.

Reading it: 1 means the video changed exactly where, and only where, the
rendered robot moved; a camera a few centimetres or degrees off moves the
rendered motion off the video's and lowers it. The value of a correct camera
depends on how closely the capsules follow the real robot's outline and on
what else moves in the view (objects the robot pushes, people, shadows,
compression noise above ``threshold``), so a threshold on it is set per
dataset: 0.7 × the median score of its sessions (docs/calibration.md: on the
toy world, at 160x120 and 320x180, correct cameras score at least 0.84 × the
median, cameras 10 cm off sideways or turned 5° at most 0.57 ×). There correct
cameras score 0.62–0.80 and the table shows what 2–10 cm and 2–5° do to it; moves along the viewing
direction change the picture least (a scale change) and are the hardest to see.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .._util.log import get_logger
from ..camera import Camera
from ..errors import OscarError

__all__ = [
    "ScoreConfig",
    "CalibrationScore",
    "calibration_score",
    "motion_iou",
    "moving",
    "body_video",
    "perturb_camera",
]

_log = get_logger(__name__)


@dataclass(frozen=True)
class ScoreConfig:
    """Settings of :func:`calibration_score` (the module docstring defines each)."""

    threshold: float = 20.0  # a pixel moves when one of its R, G, B values (0-255) changes by more
    gap: int = 1  # frames between the two frames of a pair
    width: int = 160  # working width, pixels (frames and renders are scaled to it)
    min_travel_m: float = 0.005  # metres some skeleton point must travel between a pair's frames for it to count
    max_pairs: int = 64  # at most this many pairs, at uniform times
    skeleton_dilate_px: int = 3  # keypoint embodiments: thickening of the skeleton's motion mask, working pixels

    def __post_init__(self):
        checks = {
            "threshold": self.threshold >= 0,
            "gap": self.gap >= 1,
            "width": self.width >= 8,
            "min_travel_m": self.min_travel_m >= 0,
            "max_pairs": self.max_pairs >= 1,
            "skeleton_dilate_px": self.skeleton_dilate_px >= 0,
        }
        for name, ok in checks.items():
            value = getattr(self, name)
            if not ok or not np.isfinite(value):
                raise ValueError(f"ScoreConfig.{name}: expected a finite value in its range, found {value!r}")


@dataclass
class CalibrationScore:
    """score: median IoU of the counted pairs, in [0, 1] (NaN: the robot never moves); per_pair: rows
    {t0, t1, iou, video_px, render_px, counted}; pairs: pairs counted; config: the :class:`ScoreConfig`."""

    score: float
    per_pair: list[dict] = field(default_factory=list)
    pairs: int = 0
    config: ScoreConfig = ScoreConfig()

    def to_dict(self) -> dict:
        from dataclasses import asdict

        return {
            "score": None if not np.isfinite(self.score) else self.score,
            "pairs": self.pairs,
            "config": asdict(self.config),
            "per_pair": self.per_pair,
        }


def motion_iou(a: np.ndarray, b: np.ndarray) -> float:
    """|a ∧ b| / |a ∨ b| of two boolean masks (0 when both are empty)."""
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 0.0


def _take(traj, idx: np.ndarray):
    """The trajectory's frames ``idx`` (as ``Trajectory.time_slice``, for any index list)."""
    per_frame = ("q", "gripper", "base_pose", "timestamps", "keypoints")
    return traj.replace(**{f: getattr(traj, f)[idx] for f in per_frame if getattr(traj, f) is not None})


def body_video(embodiment, traj, camera: Camera, size: tuple[int, int]) -> tuple[np.ndarray, bool]:
    """((T, H, W, 3) uint8 video of the robot's body seen by ``camera`` (already at ``size`` = (W, H)) on
    black, thin): capsules for kinematic trees (thin False), else the skeleton (thin True)."""
    import warnings

    from ..render.renderer import EmptyViewWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EmptyViewWarning)  # a camera that sees no robot scores 0; no warning
        if embodiment.uses_kinematic_tree() and len(embodiment.edges):
            from ..render.capsules import render_capsule_video

            return render_capsule_video(embodiment, traj, camera, size), False
        from ..render.skeleton_video import render_skeleton_video

        return render_skeleton_video(embodiment, traj, camera, size), True


def moving(a: np.ndarray, b: np.ndarray, threshold: float) -> np.ndarray:
    """(H, W) bool: pixels of two (H, W, 3) frames one of whose R, G, B values differs by more than ``threshold``."""
    return (np.abs(a.astype(np.int16) - b.astype(np.int16)) > threshold).any(-1)


class _Frames:
    """A video as (n_frames, read(indices)): an array, a file / PNG folder, or a reader's VideoSource."""

    def __init__(self, video, max_frames: int):
        if isinstance(video, np.ndarray):
            if video.ndim != 4 or video.shape[-1] != 3:
                raise ValueError(f"video: expected frames of shape (T, H, W, 3), found {video.shape}")
            self.n_frames, self.source, self._read = len(video), "<video>", lambda idx: video[idx]
        elif hasattr(video, "read") and hasattr(video, "n_frames"):
            self.n_frames, self.source = int(video.n_frames), str(getattr(video, "path", "<video>"))
            self._read = lambda idx: np.asarray(video.read(list(idx)))
        else:
            from ..media.video import read_video

            frames = read_video(video, max_frames=max_frames)  # the frames the trajectory covers, no more
            self.n_frames, self.source, self._read = len(frames), str(video), lambda idx: frames[idx]

    def read(self, idx: np.ndarray) -> np.ndarray:
        return self._read(np.asarray(idx, dtype=np.int64))


def calibration_score(
    video, embodiment, traj, camera: Camera, config: ScoreConfig = ScoreConfig(), *, camera_source: str = "<camera>"
) -> CalibrationScore:
    """Score ``camera`` as the calibration of ``video`` for ``traj`` of ``embodiment`` (module docstring).

    video: (T', H, W, 3) uint8 RGB frames, a video file or PNG folder, or an object with ``n_frames`` and
    ``read(indices)`` (a dataset reader's video); frame t is the trajectory's frame t, T' >= T. The camera
    is fitted to the video's size as ``oscar render`` fits it (centre crop to the aspect ratio, then scale).
    """
    import cv2

    from ..calibration.pnp import skeleton_points

    traj = embodiment.check_trajectory(traj)
    frames = _Frames(video, len(traj))
    embodiment.check_camera(camera, camera_source)
    camera.check_frames(len(traj), camera_source)
    T, cfg = len(traj), config
    if frames.n_frames < T:
        raise OscarError(
            f"{frames.source}: expected at least {T} frames (the trajectory's length), found {frames.n_frames}"
        )
    if T <= cfg.gap:
        return CalibrationScore(float("nan"), [], 0, cfg)
    starts = np.unique(np.linspace(0, T - 1 - cfg.gap, min(cfg.max_pairs, T - cfg.gap)).round().astype(np.int64))
    idx = np.unique(np.concatenate([starts, starts + cfg.gap]))
    at = {int(i): k for k, i in enumerate(idx)}
    rgb = frames.read(idx)
    H, W = rgb.shape[1:3]
    w = min(cfg.width, W)
    h = max(8, int(round(H * w / W)))
    small = np.stack([cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA) for f in rgb])
    cam = camera if (camera.intrinsics.width, camera.intrinsics.height) == (W, H) else camera.resized(W, H, "crop")
    cam = cam.resized(w, h, "stretch")  # exactly as the frames were scaled
    if cam.num_frames is not None:
        cam = replace(cam, extrinsic=cam.extrinsic[idx])
    sub = _take(traj, idx)
    body, thin = body_video(embodiment, sub, cam, (w, h))
    kernel = None
    if thin and cfg.skeleton_dilate_px > 0:
        d = cfg.skeleton_dilate_px
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * d + 1, 2 * d + 1))
    pts = skeleton_points(embodiment, sub)
    rows, values = [], []
    for t0 in starts.tolist():
        a, b = at[t0], at[t0 + cfg.gap]
        travel = np.linalg.norm(pts[b] - pts[a], axis=-1)
        counted = bool(np.nanmax(travel, initial=0.0) >= cfg.min_travel_m)
        video_mask = moving(small[a], small[b], cfg.threshold)
        render_mask = moving(body[a], body[b], cfg.threshold)
        if kernel is not None:
            render_mask = cv2.dilate(render_mask.astype(np.uint8), kernel) > 0
        iou = motion_iou(video_mask, render_mask)
        rows.append(
            {
                "t0": t0,
                "t1": t0 + cfg.gap,
                "iou": iou,
                "video_px": int(video_mask.sum()),
                "render_px": int(render_mask.sum()),
                "counted": counted,
            }
        )
        if counted:
            values.append(iou)
    score = float(np.median(values)) if values else float("nan")
    _log.info("calibration score %.3f over %d of %d pairs", score, len(values), len(rows))
    return CalibrationScore(score, rows, len(values), cfg)


def perturb_camera(camera: Camera, shift_m=(0.0, 0.0, 0.0), rotate_deg=(0.0, 0.0, 0.0)) -> Camera:
    """``camera`` (static) moved by ``shift_m`` and turned about its own centre by ``rotate_deg``, both along /
    about its OpenCV axes (x right, y down, z forward): the wrong calibrations the score must tell apart."""
    from scipy.spatial.transform import Rotation

    if not camera.is_static:
        raise ValueError("perturb_camera: expected a static camera")
    pose = np.linalg.inv(camera.world_to_cv())  # T_world_cv
    R = pose[:3, :3]
    new = np.eye(4)
    new[:3, :3] = R @ Rotation.from_rotvec(np.deg2rad(np.asarray(rotate_deg, dtype=np.float64))).as_matrix()
    new[:3, 3] = pose[:3, 3] + R @ np.asarray(shift_m, dtype=np.float64)
    return Camera(camera.intrinsics, new, "opencv", "camera_to_world", None, camera.embodiment)
