"""Skeleton video in chunks of frames: FK → guarded projection → rasterisation.

Memory stays bounded by the chunk, not the trajectory: each chunk of
``chunk_frames`` frames is taken through forward kinematics, projection and
rasterisation on its own and handed to the caller (usually an incremental video
writer, :class:`oscar_core.media.video.VideoWriter`).

The skeleton is one of the three :class:`~oscar_core.render.renderer.ConditionRenderer`
implementations (:data:`SKELETON`). Its projection is guarded for what a skeleton
needs at the image's edges (:mod:`oscar_core.render.guarded_projection`):

- an edge with one endpoint behind the camera is cut at the near plane (the
  part in front is drawn), not dropped;
- a point beyond the radius where the lens model's radial distortion stops
  growing is sent far out along its ray instead, so it can never wrap back in;
- frames in which the camera sees nothing of the robot (every point behind the
  camera or outside the image) are counted, and reported by frame number.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ..camera import Camera, Intrinsics
from .guarded_projection import NEAR, GuardedProjection, guarded_project, project_cv, to_camera
from .raster import GripperMarks, SkeletonStyle, clip_segments, rasterise
from .renderer import DEFAULT_CHUNK_FRAMES, ChunkedRenderer, RenderStats, prepare_view

__all__ = ["SKELETON", "SkeletonRenderer", "SkeletonJob", "iter_skeleton_chunks", "render_into"]


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
        cut_uv, _ = project_cv(cut, intr)
        q0, q1 = p0[cross], p1[cross]
        q0 = np.where(front_is_a[:, None], q0, cut_uv)
        q1 = np.where(front_is_a[:, None], cut_uv, q1)
        p0[cross], p1[cross] = q0, q1
        ok[cross] &= np.isfinite(cut_uv).all(-1)
    return p0, p1, ok


@dataclass(frozen=True)
class SkeletonJob:
    """A prepared skeleton render: the checked trajectory, the sized camera, the style and the colours."""

    embodiment: object
    traj: object
    camera: Camera
    style: SkeletonStyle
    device: str
    edges: np.ndarray
    point_colors: np.ndarray
    edge_colors: np.ndarray


class SkeletonRenderer(ChunkedRenderer):
    """The paper's condition: the 2D kinematic skeleton (points, edges, gripper marks) on black."""

    name = "skeleton"
    sees_nothing_of = "of the robot (every point behind the camera or outside the image)"
    video_chunk_frames = 256

    def prepare(
        self,
        embodiment,
        traj,
        camera: Camera,
        size,
        *,
        style: SkeletonStyle | None,
        resize_mode: str,
        device,
        camera_source: str,
    ) -> SkeletonJob:
        traj, camera = prepare_view(embodiment, traj, camera, size, resize_mode, camera_source)
        point_colors, edge_colors = embodiment.colors()
        return SkeletonJob(
            embodiment,
            traj,
            camera,
            style or SkeletonStyle(),
            str(device),
            embodiment.edge_index(),
            point_colors,
            edge_colors,
        )

    def render_range(
        self, job: SkeletonJob, start: int, stop: int, out: np.ndarray | None, stats: RenderStats | None
    ) -> np.ndarray:
        """Frames start:stop of ``job`` → (n, H, W, 3) uint8 (into ``out`` when given)."""
        cam = job.camera.time_slice(start, stop)  # a camera that moves per frame: this chunk's extrinsics
        intr = cam.intrinsics
        sub = job.traj.time_slice(start, stop)
        fr = job.embodiment.frames(sub, device=job.device, mount_link=cam.mount_link)
        M = cam.world_to_cv(fr.mount_pose)
        n = stop - start
        pts = np.asarray(fr.points, dtype=np.float64)
        Pc = to_camera(pts, M)
        proj = guarded_project(Pc, intr)
        gpts = np.asarray(fr.gripper_points, dtype=np.float64).reshape(n, -1, 3)
        gproj = guarded_project(to_camera(gpts, M), intr)
        edges = job.edges
        segments = _near_plane_segments(Pc, proj, edges, intr) if len(edges) else None
        marks = GripperMarks(uv=gproj.uv, visible=gproj.in_front, openness=fr.openness)
        video = rasterise(
            proj.uv,
            proj.in_front,
            edges,
            (intr.width, intr.height),
            edge_colors=job.edge_colors,
            point_colors=job.point_colors,
            grippers=marks,
            style=job.style,
            out=out,
            segments=segments,
        )
        if stats is not None:
            seen = proj.in_image.any(-1) | gproj.in_image.any(-1)
            if segments is not None:
                hi = np.array([intr.width - 0.5, intr.height - 0.5])
                crosses, _, _ = clip_segments(
                    np.where(segments[2][..., None], segments[0], 0.0),
                    np.where(segments[2][..., None], segments[1], 0.0),
                    -0.5,
                    hi,
                )
                seen |= (crosses & segments[2]).any(-1)
            stats.frames += n
            stats.empty_frames.extend((start + np.flatnonzero(~seen)).tolist())
        return video


#: the skeleton renderer (:class:`SkeletonRenderer`)
SKELETON = SkeletonRenderer()


def iter_skeleton_chunks(
    embodiment,
    traj,
    camera: Camera,
    size: tuple[int, int] | None = None,
    *,
    style: SkeletonStyle | None = None,
    resize_mode: str = "crop",
    device="cpu",
    camera_source: str = "<camera>",
    chunk_frames: int = DEFAULT_CHUNK_FRAMES,
    strict: bool = False,
    stats: RenderStats | None = None,
) -> Iterator[np.ndarray]:
    """Render ``traj`` seen by ``camera`` chunk by chunk (:meth:`SkeletonRenderer.iter_chunks`).

    size: output (width, height) pixels (None: the calibration's size; see
    :func:`oscar_core.render.skeleton_video.render_skeleton_video` for ``resize_mode``).
    Yields (n, H, W, 3) uint8 RGB arrays, n ≤ chunk_frames, each a fresh array; frames where the camera sees
    nothing of the robot give one :class:`~oscar_core.render.renderer.EmptyViewWarning` after the last chunk
    (``strict``: :class:`~oscar_core.render.renderer.EmptyViewError` at once).
    """
    return SKELETON.iter_chunks(
        embodiment,
        traj,
        camera,
        size,
        style=style,
        resize_mode=resize_mode,
        device=device,
        camera_source=camera_source,
        chunk_frames=chunk_frames,
        strict=strict,
        stats=stats,
    )


def render_into(
    embodiment,
    traj,
    camera: Camera,
    size: tuple[int, int] | None = None,
    *,
    style: SkeletonStyle | None = None,
    resize_mode: str = "crop",
    device="cpu",
    camera_source: str = "<camera>",
    chunk_frames: int = 256,
    strict: bool = False,
    stats: RenderStats | None = None,
) -> np.ndarray:
    """The whole video as one (T, H, W, 3) uint8 array, rendered chunk by chunk into it
    (:meth:`SkeletonRenderer.render_video`)."""
    return SKELETON.render_video(
        embodiment,
        traj,
        camera,
        size,
        style=style,
        resize_mode=resize_mode,
        device=device,
        camera_source=camera_source,
        chunk_frames=chunk_frames,
        strict=strict,
        stats=stats,
    )
