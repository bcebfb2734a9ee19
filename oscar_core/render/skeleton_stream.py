"""Skeleton video in chunks of frames: FK → guarded projection → rasterisation.

Memory stays bounded by the chunk, not the trajectory: each chunk of
``chunk_frames`` frames is taken through forward kinematics, projection and
rasterisation on its own and handed to the caller (usually an incremental video
writer, :class:`oscar_core.media.video.VideoWriter`).

The projection here is guarded for what a skeleton needs at the image's edges:

- an edge with one endpoint behind the camera is cut at the near plane (the
  part in front is drawn), not dropped;
- a point beyond the radius where the lens model's radial distortion stops
  growing (strong distortion folds such points back into the image) is sent far
  out along its ray instead, so it can never wrap back in;
- frames in which the camera sees nothing of the robot (every point behind the
  camera or outside the image) are counted, and reported by frame number.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from ..camera.pinhole import Camera, Intrinsics
from ..errors import OscarError
from .raster import GripperMarks, SkeletonStyle, _clip_segments, rasterise

__all__ = [
    "DEFAULT_CHUNK_FRAMES",
    "NEAR",
    "EmptyViewWarning",
    "EmptyViewError",
    "RenderStats",
    "GuardedProjection",
    "guarded_project",
    "distortion_valid_radius",
    "iter_skeleton_chunks",
    "format_frames",
]

DEFAULT_CHUNK_FRAMES = 16
NEAR = 1e-6  # metres: a point is in front of the camera when its depth is > NEAR (as camera.project)


class EmptyViewWarning(UserWarning):
    """The camera sees nothing of the robot in some frames; the video is written anyway."""


class EmptyViewError(OscarError):
    """``strict``: the camera sees nothing of the robot in some frames."""


@dataclass
class RenderStats:
    """What one streamed render saw: ``frames`` rendered, ``empty_frames`` (frame indices
    where every skeleton and gripper point is behind the camera or outside the image)."""

    frames: int = 0
    empty_frames: list[int] = field(default_factory=list)


def format_frames(frames: list[int], limit: int = 8) -> str:
    """``[0, 1, 2, 5, 7, 8]`` → ``"0-2, 5, 7-8"`` (at most ``limit`` runs, then "…")."""
    runs: list[tuple[int, int]] = []
    for f in frames:
        if runs and f == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], f)
        else:
            runs.append((f, f))
    text = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:limit])
    return text + (f", … ({len(runs) - limit} more runs)" if len(runs) > limit else "")


# ----------------------------------------------------------------------------- projection


@functools.lru_cache(maxsize=256)
def distortion_valid_radius(distortion: tuple[float, ...]) -> float:
    """Largest normalised radius r = |(x/z, y/z)| up to which the radial model
    r · radial(r) still grows (inf when it grows everywhere up to r = 50).

    Beyond it the polynomial folds back: points further out would land nearer the
    centre, or on the opposite side. Tangential and thin-prism terms are small
    and ignored here.
    """
    if not distortion:
        return float("inf")
    k = tuple(distortion) + (0.0,) * (12 - len(distortion))
    k1, k2, _, _, k3, k4, k5, k6 = k[:8]
    r = np.concatenate([np.linspace(0.0, 2.0, 4001)[1:], np.geomspace(2.0, 50.0, 4000)[1:]])
    r2 = r * r
    with np.errstate(all="ignore"):
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        rd = r * radial
    grows = np.isfinite(rd) & (np.diff(np.concatenate([[0.0], rd])) > 0) & (radial > 0)
    bad = np.flatnonzero(~grows)
    if bad.size == 0:
        return float("inf")
    return float(r[bad[0] - 1]) if bad[0] > 0 else 0.0


@dataclass(frozen=True)
class GuardedProjection:
    """uv: (..., 2) pixels; depth: (...,) metres; in_front: (...,) bool (depth > NEAR and
    finite); in_image: (...,) bool (in front and inside the pixel-edge extent)."""

    uv: np.ndarray
    depth: np.ndarray
    in_front: np.ndarray
    in_image: np.ndarray


def _project_cv(P: np.ndarray, intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Project camera-frame points (..., 3) with depth > 0; returns (uv (..., 2), folded (...,) bool)."""
    from ..camera.pinhole import project_points_cv

    proj = project_points_cv(P, intr, near=NEAR)
    uv = proj.uv
    r_valid = distortion_valid_radius(tuple(intr.distortion))
    if not np.isfinite(r_valid):
        return uv, np.zeros(P.shape[:-1], bool)
    with np.errstate(all="ignore"):
        x, y = P[..., 0] / P[..., 2], P[..., 1] / P[..., 2]
        r = np.hypot(x, y)
        folded = np.isfinite(r) & (r > r_valid)
        if folded.any():
            # far out along the undistorted ray: never back inside the image
            far = 4.0 * (intr.width + intr.height) / (min(intr.fx, intr.fy) * np.maximum(r, 1e-12))
            s = np.maximum(1.0, far)
            lin = np.stack([intr.cx + intr.fx * x * s, intr.cy + intr.fy * y * s], axis=-1)
            uv = np.where(folded[..., None], lin, uv)
    return uv, folded


def guarded_project(points_cv, intr: Intrinsics) -> GuardedProjection:
    """Project camera-frame points (..., 3) metres (OpenCV: x right, y down, z forward)
    to pixels, without the fold-back of strong distortion (see module doc)."""
    P = np.asarray(points_cv, dtype=np.float64)
    uv, _ = _project_cv(P, intr)
    z = P[..., 2]
    with np.errstate(invalid="ignore"):
        in_front = (z > NEAR) & np.isfinite(P).all(-1)
        u, v = uv[..., 0], uv[..., 1]
        in_image = in_front & (u >= -0.5) & (u < intr.width - 0.5) & (v >= -0.5) & (v < intr.height - 0.5)
    return GuardedProjection(uv, z, in_front, in_image)


def _to_camera(points: np.ndarray, M: np.ndarray) -> np.ndarray:
    """World points (T, N, 3) → OpenCV camera frame with M (4, 4) or (T, 4, 4)."""
    R, t = M[..., :3, :3], M[..., :3, 3]
    with np.errstate(all="ignore"):
        if M.ndim == 2:
            return points @ R.T + t
        return points @ np.swapaxes(R, -1, -2) + t[:, None, :]


def _near_plane_segments(Pc: np.ndarray, proj: GuardedProjection, edges: np.ndarray, intr: Intrinsics):
    """Edge endpoints in pixels with edges crossing the near plane cut there.

    Pc: (T, K, 3) camera-frame points; returns (p0, p1 (T, E, 2), ok (T, E)).
    """
    a, b = Pc[:, edges[:, 0]], Pc[:, edges[:, 1]]
    fa, fb = proj.in_front[:, edges[:, 0]], proj.in_front[:, edges[:, 1]]
    p0, p1 = proj.uv[:, edges[:, 0]].copy(), proj.uv[:, edges[:, 1]].copy()
    ok = fa | fb
    cross = fa ^ fb
    if cross.any():
        ai, bi = a[cross], b[cross]  # (M, 3)
        front_is_a = fa[cross]
        f_pt = np.where(front_is_a[:, None], ai, bi)
        r_pt = np.where(front_is_a[:, None], bi, ai)
        zc = 2.0 * NEAR
        with np.errstate(all="ignore"):
            s = (f_pt[:, 2] - zc) / (f_pt[:, 2] - r_pt[:, 2])
            cut = f_pt + s[:, None] * (r_pt - f_pt)
        cut[:, 2] = zc
        cut_uv, _ = _project_cv(cut, intr)
        q0, q1 = p0[cross], p1[cross]
        q0 = np.where(front_is_a[:, None], q0, cut_uv)
        q1 = np.where(front_is_a[:, None], cut_uv, q1)
        p0[cross], p1[cross] = q0, q1
        ok[cross] &= np.isfinite(cut_uv).all(-1)
    return p0, p1, ok


# ------------------------------------------------------------------------------ streaming


@dataclass(frozen=True)
class _Job:
    embodiment: object
    traj: object
    camera: Camera
    style: SkeletonStyle
    device: str
    edges: np.ndarray
    point_colors: np.ndarray
    edge_colors: np.ndarray


def _prepare(embodiment, traj, camera: Camera, size, style, resize_mode, device, camera_source) -> _Job:
    traj = embodiment.check_trajectory(traj)
    embodiment.check_camera(camera, camera_source)
    camera.check_frames(len(traj), camera_source)  # a per-frame camera needs one extrinsic per trajectory frame
    if size is not None and (size[0], size[1]) != (camera.intrinsics.width, camera.intrinsics.height):
        camera = camera.resized(size[0], size[1], mode=resize_mode)
    point_colors, edge_colors = embodiment.colors()
    return _Job(embodiment, traj, camera, style or SkeletonStyle(), str(device), embodiment.edge_index(),
                point_colors, edge_colors)


def _render_range(job: _Job, start: int, stop: int, out: np.ndarray | None, stats: RenderStats | None) -> np.ndarray:
    """Frames start:stop of ``job`` → (n, H, W, 3) uint8 (into ``out`` when given)."""
    cam = job.camera.time_slice(start, stop)  # a camera that moves per frame: this chunk's extrinsics
    intr = cam.intrinsics
    sub = job.traj.time_slice(start, stop)
    fr = job.embodiment.frames(sub, device=job.device, mount_link=cam.mount_link)
    M = cam.world_to_cv(fr.mount_pose)
    n = stop - start
    pts = np.asarray(fr.points, dtype=np.float64)
    Pc = _to_camera(pts, M)
    proj = guarded_project(Pc, intr)
    gpts = np.asarray(fr.gripper_points, dtype=np.float64).reshape(n, -1, 3)
    gproj = guarded_project(_to_camera(gpts, M), intr)
    edges = job.edges
    segments = _near_plane_segments(Pc, proj, edges, intr) if len(edges) else None
    marks = GripperMarks(uv=gproj.uv, visible=gproj.in_front, openness=fr.openness)
    video = rasterise(proj.uv, proj.in_front, edges, (intr.width, intr.height), edge_colors=job.edge_colors,
                      point_colors=job.point_colors, grippers=marks, style=job.style, out=out, segments=segments)
    if stats is not None:
        seen = proj.in_image.any(-1) | gproj.in_image.any(-1)
        if segments is not None:
            hi = np.array([intr.width - 0.5, intr.height - 0.5])
            crosses, _, _ = _clip_segments(np.where(segments[2][..., None], segments[0], 0.0),
                                           np.where(segments[2][..., None], segments[1], 0.0), -0.5, hi)
            seen |= (crosses & segments[2]).any(-1)
        stats.frames += n
        stats.empty_frames.extend((start + np.flatnonzero(~seen)).tolist())
    return video


def _empty_message(source: str, empty: list[int], total: int) -> str:
    return (f"{source}: the camera sees nothing of the robot (every point behind the camera or outside "
            f"the image) in {len(empty)} of {total} frames: {format_frames(empty)}")


def stream_chunks(total: int, render: Callable[[int, int, RenderStats], np.ndarray], chunk_frames: int,
                  strict: bool, stats: RenderStats | None, message: Callable[[list[int], int], str]):
    """The chunk loop every condition renderer shares: yields ``render(start, stop, stats)`` for consecutive
    ranges of at most ``chunk_frames`` of ``total`` frames. Frames ``render`` records as empty in
    ``stats.empty_frames`` give one :class:`EmptyViewWarning` after the last chunk, worded by
    ``message(empty frames, total)``; ``strict`` raises :class:`EmptyViewError` as soon as a chunk has one."""
    stats = stats if stats is not None else RenderStats()
    for start in range(0, total, chunk_frames):
        before = len(stats.empty_frames)
        chunk = render(start, min(total, start + chunk_frames), stats)
        if strict and len(stats.empty_frames) > before:
            raise EmptyViewError(message(stats.empty_frames[before:], total) + " (strict)")
        yield chunk
    if stats.empty_frames:
        warnings.warn(message(stats.empty_frames, total), EmptyViewWarning, stacklevel=3)


def render_whole(total: int, height: int, width: int, render: Callable[[int, int, np.ndarray, RenderStats], object],
                 chunk_frames: int, strict: bool, stats: RenderStats | None,
                 message: Callable[[list[int], int], str]) -> np.ndarray:
    """The loop every condition's whole-video renderer shares: a (total, height, width, 3) uint8 video whose
    consecutive ranges of at most ``chunk_frames`` frames ``render(start, stop, out[start:stop], stats)`` fills.
    Frames ``render`` records as empty in ``stats.empty_frames`` give one :class:`EmptyViewWarning` at the
    end, worded by ``message(empty frames, total)`` (``strict``: :class:`EmptyViewError` instead)."""
    stats = stats if stats is not None else RenderStats()
    out = np.empty((total, height, width, 3), np.uint8)
    for start in range(0, total, chunk_frames):
        stop = min(total, start + chunk_frames)
        render(start, stop, out[start:stop], stats)
    if stats.empty_frames:
        text = message(stats.empty_frames, total)
        if strict:
            raise EmptyViewError(text + " (strict)")
        warnings.warn(text, EmptyViewWarning, stacklevel=3)
    return out


def iter_skeleton_chunks(embodiment, traj, camera: Camera, size: tuple[int, int] | None = None, *,
                         style: SkeletonStyle | None = None, resize_mode: str = "crop", device="cpu",
                         camera_source: str = "<camera>", chunk_frames: int = DEFAULT_CHUNK_FRAMES,
                         strict: bool = False, stats: RenderStats | None = None) -> Iterator[np.ndarray]:
    """Render ``traj`` seen by ``camera`` chunk by chunk.

    size: output (width, height) pixels (None: the calibration's size; see
    :func:`oscar_core.render.skeleton_video.render_skeleton_video` for ``resize_mode``).
    chunk_frames: frames per chunk (memory is about chunk_frames × W × H × 3 bytes
    plus the writer's). Yields (n, H, W, 3) uint8 RGB arrays, n ≤ chunk_frames,
    each a fresh array. After the last chunk, frames where the camera sees nothing
    of the robot give one :class:`EmptyViewWarning` naming them; ``strict`` raises
    :class:`EmptyViewError` instead, as soon as a chunk has such a frame.
    stats: optional :class:`RenderStats` filled as chunks are rendered.
    """
    if chunk_frames < 1:
        raise ValueError(f"chunk_frames: expected a positive number of frames, found {chunk_frames}")
    job = _prepare(embodiment, traj, camera, size, style, resize_mode, device, camera_source)
    yield from stream_chunks(len(job.traj), lambda start, stop, st: _render_range(job, start, stop, None, st),
                             chunk_frames, strict, stats, lambda empty, T: _empty_message(camera_source, empty, T))


def render_into(embodiment, traj, camera: Camera, size: tuple[int, int] | None = None, *,
                style: SkeletonStyle | None = None, resize_mode: str = "crop", device="cpu",
                camera_source: str = "<camera>", chunk_frames: int = 256, strict: bool = False,
                stats: RenderStats | None = None) -> np.ndarray:
    """The whole video as one (T, H, W, 3) uint8 array, rendered chunk by chunk into it."""
    job = _prepare(embodiment, traj, camera, size, style, resize_mode, device, camera_source)
    intr = job.camera.intrinsics
    return render_whole(len(job.traj), intr.height, intr.width,
                        lambda start, stop, out, st: _render_range(job, start, stop, out, st), chunk_frames, strict,
                        stats, lambda empty, T: _empty_message(camera_source, empty, T))
