"""``filter``: the paper's four filters (length, static camera, meaningful action, visible skeleton) and a joint-spike check.

Each filter measures one number per episode and compares it with a
threshold from :class:`FilterConfig`; every measured value is kept in the
manifest (``filter_<name>``) and a rejected episode names the first failing
filter in ``filter_reason`` (``"<name>: <value> <op> <threshold>"``) with the
value in ``filter_value``.

Measurements (all on the episode's own trajectory, camera and video):

* ``length`` — frames. Paper: at least 70.
* ``camera_motion`` — median background image motion, in image diagonals per
  second. Dense optical flow (Farneback) between frames ``motion_gap_s`` apart
  at ``motion_pairs`` uniform times, on a ``motion_width``-pixel-wide grey
  copy; the projected skeleton (thickened by ``motion_mask_px``) is masked out
  and so are flat pixels (no texture, no measurable flow); the median flow
  magnitude of what is left is the frame pair's motion. A static camera
  gives ~0 even while the arm and objects move (they are a minority of the
  pixels); a panning or shaking camera moves the whole background. NaN (not
  measurable: too little texture) passes.
* ``action`` — the largest distance, metres, any skeleton point travels from
  its first-frame position (forward kinematics through the embodiment; hands:
  their keypoints).
* ``visible`` — fraction of projected skeleton points (all frames × points)
  in front of the camera and inside the image.
* ``spike_joint`` — largest joint speed |Δq|·fps, rad/s (or m/s for prismatic
  joints); ``spike_point`` — largest skeleton-point speed, m/s. A teleoperated
  arm stays far below the defaults (Franka's joint limit is 2.6 rad/s, its
  hand's ~1.7 m/s); a one-frame glitch of 1 rad at 15 fps reads 15 rad/s.
* ``calibration_score`` — how well the robot rendered through the episode's
  camera lines up with its video, in [0, 1]
  (:func:`oscar_core.calibration.score.calibration_score`, docs/calibration.md).
  Off by default (``min_calibration_score`` 0: not measured, NaN); it renders
  the capsule body of up to 128 frames per episode.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from ._episode import EPISODE_ERRORS, camera_at_video_size, load_row, reason_of

__all__ = [
    "FilterConfig",
    "FilterStage",
    "FILTERS",
    "measure_camera_motion",
    "measure_action",
    "measure_visible",
    "measure_spikes",
    "decide",
]

FILTERS = ("length", "camera_motion", "action", "visible", "spike_joint", "spike_point", "calibration_score")


@dataclass(frozen=True)
class FilterConfig:
    """Thresholds of ``oscar data filter`` (each overridable with ``--set name=value``)."""

    min_length: int = 70  # frames; the paper's length filter
    max_camera_motion: float = 0.02  # image diagonals / s of median background flow (2 % of the diagonal per second)
    min_action: float = 0.03  # metres some skeleton point must travel from its start (3 cm)
    min_visible: float = 0.8  # fraction of projected skeleton points inside the image
    max_joint_speed: float = 10.0  # rad/s (m/s for prismatic joints); 4x Franka's fastest joint limit
    max_point_speed: float = 5.0  # m/s of any skeleton point between two frames
    motion_pairs: int = 8  # frame pairs for camera motion, at uniform times
    motion_gap_s: float = 0.2  # seconds between the two frames of a pair
    motion_width: int = 160  # pixels; frames are resized to this width for the flow
    motion_mask_px: int = 6  # pixels (at motion_width) the skeleton mask is thickened by
    min_texture: float = 8.0  # grey-level gradient a pixel needs to count as background texture
    min_calibration_score: float = 0.0  # least calibration score (0-1, docs/calibration.md); 0: off, not measured

    @classmethod
    def from_overrides(cls, items: list[str] | None) -> FilterConfig:
        """Defaults with ``name=value`` overrides; ValueError naming the field on a bad name or value."""
        kinds = {f.name: f.type for f in fields(cls)}
        values: dict[str, Any] = {}
        for item in items or []:
            name, sep, text = item.partition("=")
            if not sep or name not in kinds:
                raise ValueError(f"--set: expected name=value with a name in {sorted(kinds)}, found {item!r}")
            try:
                values[name] = int(text) if kinds[name] == "int" else float(text)
            except ValueError:
                raise ValueError(f"--set {name}: expected a number ({kinds[name]}), found {text!r}") from None
            least = 1 if name in ("motion_pairs", "motion_width") else 0  # every threshold is a size, count or rate
            if not math.isfinite(values[name]) or values[name] < least:
                raise ValueError(f"--set {name}: expected a finite number >= {least} ({kinds[name]}), found {text!r}")
        return cls(**values)

    def to_dict(self) -> dict:
        return asdict(self)


def _skeleton_mask(
    uv: np.ndarray, usable: np.ndarray, edges: np.ndarray, shape: tuple[int, int], thick: int
) -> np.ndarray:
    """(H, W) bool: True where the skeleton (points + edges of one frame's uv (K, 2) pixels) is drawn."""
    import cv2

    m = np.zeros(shape, np.uint8)
    pts = np.round(np.nan_to_num(uv, nan=-1e6)).astype(np.int64).clip(-(10**6), 10**6)
    for a, b in np.asarray(edges).reshape(-1, 2):
        if usable[a] and usable[b]:
            cv2.line(m, tuple(int(v) for v in pts[a]), tuple(int(v) for v in pts[b]), 1, thickness=max(1, 2 * thick))
    for k in range(len(pts)):
        if usable[k]:
            cv2.circle(m, tuple(int(v) for v in pts[k]), thick, 1, -1)
    return m.astype(bool)


def measure_camera_motion(
    video, uv: np.ndarray | None, usable: np.ndarray | None, edges: np.ndarray, cfg: FilterConfig = FilterConfig()
) -> float:
    """Median background motion of ``video`` in image diagonals per second (NaN: not measurable).

    uv: (T, K, 2) projected skeleton pixels at the video's size, usable: (T, K)
    bool — masked out of the background (None: nothing masked).
    """
    import cv2

    T, fps = video.n_frames, float(video.fps)
    gap = max(1, int(round(cfg.motion_gap_s * fps)))
    if T <= gap:
        return float("nan")
    starts = np.unique(np.linspace(0, T - 1 - gap, max(1, cfg.motion_pairs)).round().astype(int))
    idx = sorted(set(starts.tolist()) | set((starts + gap).tolist()))
    frames = video.read(idx)
    at = {i: k for k, i in enumerate(idx)}
    H, W = frames.shape[1:3]
    w = min(cfg.motion_width, W)
    s = w / W
    h = max(8, int(round(H * s)))
    diag = float(np.hypot(w, h))
    speeds = []
    for t0 in starts:
        a = cv2.cvtColor(cv2.resize(frames[at[t0]], (w, h), interpolation=cv2.INTER_AREA), cv2.COLOR_RGB2GRAY)
        b = cv2.cvtColor(cv2.resize(frames[at[t0 + gap]], (w, h), interpolation=cv2.INTER_AREA), cv2.COLOR_RGB2GRAY)
        flow = cv2.calcOpticalFlowFarneback(a, b, None, 0.5, 3, 15, 3, 5, 1.2, 0)
        gx = cv2.Sobel(a, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(a, cv2.CV_32F, 0, 1, ksize=3)
        keep = np.hypot(gx, gy) >= cfg.min_texture * 4  # Sobel 3x3 gains 4x on a unit step
        if uv is not None:
            for t in (t0, t0 + gap):
                keep &= ~_skeleton_mask(uv[t] * s, usable[t], edges, (h, w), cfg.motion_mask_px)
        if keep.mean() < 0.01:
            continue
        mag = np.hypot(flow[..., 0], flow[..., 1])[keep]
        speeds.append(float(np.median(mag)) / diag / (gap / fps))
    return float(np.median(speeds)) if speeds else float("nan")


def measure_action(points: np.ndarray) -> float:
    """Largest travel (metres) of any point from its first-frame position; points: (T, K, 3) metres (NaN: missing)."""
    p = np.asarray(points, dtype=np.float64)
    d = np.linalg.norm(p - p[:1], axis=-1)
    return float(np.nanmax(d)) if np.isfinite(d).any() else 0.0


def measure_visible(uv: np.ndarray, usable: np.ndarray, width: int, height: int) -> float:
    """Fraction of (T, K) projected points usable (in front) and inside the width×height image."""
    inside = usable & (uv[..., 0] >= 0) & (uv[..., 0] < width) & (uv[..., 1] >= 0) & (uv[..., 1] < height)
    return float(inside.mean()) if inside.size else 0.0


def measure_spikes(q: np.ndarray, points: np.ndarray, fps: float) -> tuple[float, float]:
    """(largest joint speed, largest point speed): q (T, J) rad or m, points (T, K, 3) m → (rad/s, m/s)."""
    q = np.asarray(q, dtype=np.float64)
    js = float(np.abs(np.diff(q, axis=0)).max() * fps) if q.shape[0] > 1 and q.shape[1] else 0.0
    p = np.asarray(points, dtype=np.float64)
    v = np.linalg.norm(np.diff(p, axis=0), axis=-1) * fps if p.shape[0] > 1 else np.zeros(1)
    ps = float(np.nanmax(v)) if np.isfinite(v).any() else 0.0
    return js, ps


def decide(m: dict[str, float], cfg: FilterConfig) -> tuple[str, float, str] | None:
    """(filter name, value, reason) of the first failing filter in ``m`` (measurements by name), or None."""
    checks = [
        ("length", m["length"] < cfg.min_length, "<", cfg.min_length),
        ("camera_motion", m["camera_motion"] > cfg.max_camera_motion, ">", cfg.max_camera_motion),
        ("action", m["action"] < cfg.min_action, "<", cfg.min_action),
        ("visible", m["visible"] < cfg.min_visible, "<", cfg.min_visible),
        ("spike_joint", m["spike_joint"] > cfg.max_joint_speed, ">", cfg.max_joint_speed),
        ("spike_point", m["spike_point"] > cfg.max_point_speed, ">", cfg.max_point_speed),
        (
            "calibration_score",
            m.get("calibration_score", math.nan) < cfg.min_calibration_score,
            "<",
            cfg.min_calibration_score,
        ),
    ]
    for name, failed, op, thr in checks:
        if failed:  # NaN compares False: an unmeasurable value passes
            return name, float(m[name]), f"{name}: {m[name]:.4g} {op} {thr:g}"
    return None


@dataclass(frozen=True)
class FilterStage:
    """Measure and decide every live row: ``fn(rows, shard=...) -> rows`` with ``filter_*`` columns."""

    config: FilterConfig = FilterConfig()
    plugin_paths: tuple[str, ...] = ()
    name: str = "filter"

    def __call__(self, rows: list[dict], shard: str = "") -> list[dict]:
        from .manifest import is_alive

        return [self.one(r) if is_alive(r) else r for r in rows]

    def measure(self, row: dict) -> dict[str, float]:
        from ..render.skeleton_video import project_skeleton

        cfg = self.config
        ep, emb = load_row(row, self.plugin_paths)
        traj = emb.check_trajectory(ep.trajectory)
        m = {"length": float(len(traj))}
        W, H = row.get("width"), row.get("height")
        cam = camera_at_video_size(ep.camera, W, H)
        W, H = cam.intrinsics.width, cam.intrinsics.height
        frames = emb.frames(traj, mount_link=cam.mount_link)
        proj = project_skeleton(emb, traj, cam)
        m["action"] = measure_action(frames.points)
        m["visible"] = measure_visible(proj.uv, proj.usable, W, H)
        m["spike_joint"], m["spike_point"] = measure_spikes(traj.q, frames.points, traj.fps)
        if m["length"] >= cfg.min_length and ep.video is not None:
            m["camera_motion"] = measure_camera_motion(ep.video, proj.uv, proj.usable, emb.edge_index(), cfg)
        else:
            m["camera_motion"] = float("nan")  # not measured: already rejected by length, or no video
        m["calibration_score"] = float("nan")  # not measured: off, already rejected by length, or no video
        if cfg.min_calibration_score > 0 and m["length"] >= cfg.min_length and ep.video is not None:
            from ..calibration.score import calibration_score

            m["calibration_score"] = calibration_score(ep.video, emb, traj, cam).score
        return m

    def one(self, row: dict) -> dict:
        out = dict(row, filter_status="ok", filter_reason=None, filter_value=None)
        try:
            m = self.measure(row)
        except EPISODE_ERRORS as exc:
            out.update(filter_status="rejected", filter_reason=f"unreadable: {reason_of(exc)}")
            return out
        for k in FILTERS:
            out[f"filter_{k}"] = float(m[k])
        verdict = decide(m, self.config)
        if verdict is not None:
            name, value, reason = verdict
            out.update(filter_status="rejected", filter_reason=reason, filter_value=value)
        return out
