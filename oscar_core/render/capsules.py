"""The capsule body: a robot drawn as shaded capsules along its skeleton edges, two fingers per gripper.

A mesh condition for any kinematic tree, with or without visual geometry in its
URDF: every skeleton edge (``Embodiment.edges``) is a capsule between the two
skeleton points FK gives, its radius tapering from :data:`RADIUS_BASE` of the
robot's reach at the first edge to :data:`RADIUS_TIP` at the last (the toy
world draws its robots with exactly these capsules: :mod:`oscar_core.toyworld`);
each gripper gets two finger capsules at its indicator point whose gap follows
the gripper's openness, so the gripper state shows through geometry as a mesh's
fingers do. Triangles are drawn by the mesh condition's own rasteriser
(:func:`oscar_core.render.mesh.draw_frames`: the skeleton's projection, a fixed
colour per part, flat headlight shading, a z-buffer, black canvas).

The condition is named ``capsules`` (:mod:`oscar_core.render.conditions`). Units:
metres in the world, pixels in images. Memory streams like the skeleton's:
chunks of frames, each frame rasterised on its own.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from ..kinematics.visual import capsule_mesh
from ..kinematics.workspace import joint_limits, open_fk, reach_of
from .guarded_projection import project_cv, to_camera
from .mesh import draw_frames, link_palette, record_empty
from .renderer import DEFAULT_CHUNK_FRAMES, ChunkedRenderer, RenderStats, prepare_view

__all__ = [
    "CAPSULES",
    "CapsuleRenderer",
    "CapsuleJob",
    "RADIUS_BASE",
    "RADIUS_TIP",
    "CapsuleStyle",
    "link_radii",
    "body_reach",
    "finger_axes",
    "body_vertices",
    "iter_capsule_chunks",
    "render_capsule_video",
]

#: capsule radius at the first skeleton edge, as a fraction of the robot's reach
RADIUS_BASE = 0.07
#: capsule radius at the last skeleton edge, as a fraction of the robot's reach
RADIUS_TIP = 0.045
_TAPER = 0.025  # RADIUS_BASE - RADIUS_TIP, as a literal


def link_radii(n_edges: int, reach: float) -> np.ndarray:
    """(E,) capsule radii, metres: ``RADIUS_BASE · reach`` at the first edge tapering linearly to
    ``RADIUS_TIP · reach`` at the last (a lone edge gets the base radius)."""
    if n_edges == 0:
        return np.zeros(0)
    f = np.linspace(0.0, 1.0, n_edges) if n_edges > 1 else np.zeros(1)
    return reach * (RADIUS_BASE - _TAPER * f)  # written so as to give the toy world's radii bit for bit


@dataclass(frozen=True)
class CapsuleStyle:
    """How the capsule body looks.

    reach: the robot's reach in metres, which sets every size (None: :func:`body_reach`);
    segments: facets around each capsule; fingers: draw two finger capsules per gripper;
    ambient: light on faces seen edge-on (0–1), as :class:`oscar_core.render.mesh.MeshStyle`.
    """

    reach: float | None = None
    segments: int = 12
    fingers: bool = True
    ambient: float = 0.3

    def __post_init__(self):
        if self.reach is not None and not (np.isfinite(self.reach) and self.reach > 0):
            raise ValueError(f"CapsuleStyle.reach: expected a positive number of metres, found {self.reach!r}")
        if int(self.segments) < 4:
            raise ValueError(f"CapsuleStyle.segments: expected at least 4, found {self.segments!r}")


def body_reach(embodiment, samples: int = 768, seed: int = 0) -> float:
    """The robot's reach, metres: the 90th percentile of the end-effector's distance from the base point
    over ``samples`` configurations drawn uniformly inside the joint limits (shrunk by 5 %; unlimited
    joints: [−π, π]) with a fixed ``seed``, grippers open. The end-effector is the first gripper's
    indicator point, else the last skeleton point; the base is skeleton point 0 (mean over samples).
    Deterministic per embodiment (cached on it); the toy world's per-episode reach is the same statistic
    (:func:`oscar_core.kinematics.workspace.reach_of`) over its own draws."""
    cache = embodiment.__dict__.setdefault("_capsule_reach", {})
    key = (samples, seed)
    if key not in cache:
        lo, hi = joint_limits(embodiment)
        q = lo + np.random.default_rng(seed).uniform(0, 1, (samples, len(lo))) * (hi - lo)
        cache[key] = reach_of(*open_fk(embodiment, q))
    return cache[key]


def _unit_capsule(segments: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A capsule of radius 1 whose hemisphere centres sit at z = ±1: vertices (V, 3), side (V,) ±1
    (which hemisphere a vertex belongs to), faces (F, 3), closed and wound outward."""
    v, f = capsule_mesh(1.0, 2.0, segments)
    return v, np.sign(v[:, 2]), f


def _frame_of(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (..., 3) perpendicular to ``axis`` (..., 3, unit) and to each other."""
    helper = np.where((np.abs(axis[..., 2]) > 0.9)[..., None], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    return u, np.cross(axis, u)


def _place(unit: np.ndarray, side: np.ndarray, a: np.ndarray, b: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """World vertices (T, V, 3) of capsules from ``a`` to ``b`` (T, 3) of ``radius`` (T,) metres."""
    d = b - a
    length = np.linalg.norm(d, axis=-1)
    axis = np.where((length > 1e-12)[:, None], d / np.maximum(length, 1e-12)[:, None], [0.0, 0.0, 1.0])
    u, w = _frame_of(axis)
    r = radius[:, None]
    x, y = unit[None, :, 0] * r, unit[None, :, 1] * r
    z = (unit[None, :, 2] - side[None]) * r + side[None] * (length / 2)[:, None]
    mid = (a + b) / 2
    return mid[:, None] + x[..., None] * u[:, None] + y[..., None] * w[:, None] + z[..., None] * axis[:, None]


def finger_axes(points: np.ndarray, gripper_point: np.ndarray, min_distance: float) -> np.ndarray:
    """(T, 3) unit approach direction of a gripper: from the skeleton point nearest its indicator point
    (among those at least ``min_distance`` metres from it on average) to the indicator point.

    points: (T, K, 3) skeleton points; gripper_point: (T, 3), metres.
    """
    dist = np.linalg.norm(points - gripper_point[:, None], axis=-1).mean(0)  # (K,)
    far = np.flatnonzero(dist >= min_distance)
    k = int(far[np.argmin(dist[far])]) if len(far) else int(np.argmax(dist))
    d = gripper_point - points[:, k]
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    return np.where(n > 1e-12, d / np.maximum(n, 1e-12), [0.0, 0.0, -1.0])


def body_vertices(
    frames, edges: np.ndarray, reach: float, style: CapsuleStyle | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The body's triangles for every frame.

    frames: :class:`~oscar_core.plugin.embodiment.SkeletonFrames` (points (T, K, 3), gripper_points (T, G, 3),
    openness (T, G)); edges: (E, 2) indices into the points; reach: metres. Returns world vertices
    (T, V, 3) metres, faces (F, 3) and face_part (F,): the part each face belongs to, edges 0…E−1 then
    grippers E…E+G−1 (both fingers of a gripper are one part).

    A finger is a capsule of radius 0.5·r_tip and length 3·r_tip (r_tip = the last edge's radius) from
    the indicator point along the approach direction (:func:`finger_axes`), offset sideways by
    ``r_tip · (0.5 + 1.5 · openness)``: touching when closed, a gap of two finger widths when open.
    """
    style = style or CapsuleStyle()
    unit, side, tri = _unit_capsule(int(style.segments))
    pts = np.asarray(frames.points, dtype=np.float64)
    T = pts.shape[0]
    radii = link_radii(len(edges), reach)
    verts, faces, part = [], [], []

    def add(v, p):  # v: (T, V_part, 3)
        faces.append(tri + sum(x.shape[1] for x in verts))
        verts.append(v)
        part.append(np.full(len(tri), p))

    for e, (i, j) in enumerate(np.asarray(edges, dtype=np.int64).reshape(-1, 2)):
        add(_place(unit, side, pts[:, i], pts[:, j], np.full(T, radii[e])), e)
    if style.fingers and frames.gripper_points.shape[1]:
        r_tip = float(radii[-1]) if len(radii) else RADIUS_TIP * reach
        for g in range(frames.gripper_points.shape[1]):
            p = np.asarray(frames.gripper_points[:, g], dtype=np.float64)
            axis = finger_axes(pts, p, 2.0 * r_tip)
            u, _ = _frame_of(axis)
            gap = r_tip * (0.5 + 1.5 * np.clip(np.asarray(frames.openness[:, g], dtype=np.float64), 0.0, 1.0))
            for s in (-1.0, 1.0):
                a = p + s * gap[:, None] * u
                add(_place(unit, side, a, a + 3.0 * r_tip * axis, np.full(T, 0.5 * r_tip)), len(edges) + g)
    if not verts:
        return np.zeros((T, 0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    return (
        np.concatenate(verts, axis=1),
        np.concatenate(faces).astype(np.int64),
        np.concatenate(part).astype(np.int64),
    )


@dataclass(frozen=True)
class CapsuleJob:
    """A prepared capsule render: the checked trajectory, the sized camera, the style, the reach, the colours."""

    embodiment: object
    traj: object
    camera: Camera
    style: CapsuleStyle
    reach: float
    edges: np.ndarray
    face_rgb: np.ndarray
    device: str


def _vertices_cv(job: CapsuleJob, start: int, stop: int):
    cam = job.camera.time_slice(start, stop)
    sub = job.traj.time_slice(start, stop)
    fr = job.embodiment.frames(sub, job.device, mount_link=cam.mount_link)
    world, faces, _ = body_vertices(fr, job.edges, job.reach, job.style)
    M = cam.world_to_cv(fr.mount_pose if cam.mount_link else None)
    Pc = to_camera(world, M)
    uv, folded = project_cv(Pc, cam.intrinsics)
    return cam, Pc, uv, folded, faces


class CapsuleRenderer(ChunkedRenderer):
    """Shaded capsules along the skeleton's edges, two fingers per gripper, on black."""

    name = "capsules"
    sees_nothing_of = "of the robot's capsule body"
    video_chunk_frames = 64

    def prepare(
        self,
        embodiment,
        traj,
        camera: Camera,
        size,
        *,
        style: CapsuleStyle | None,
        resize_mode: str,
        device,
        camera_source: str,
    ) -> CapsuleJob:
        """Also raises :class:`~oscar_core.errors.PluginError` for an embodiment without a kinematic tree or
        without skeleton edges."""
        from ..errors import PluginError

        if not embodiment.uses_kinematic_tree():
            raise PluginError(
                f"embodiment {embodiment.name!r} computes its points itself (no kinematic tree); "
                "the capsule body needs a skeleton from FK"
            )
        if len(embodiment.edges) == 0:
            raise PluginError(
                f"embodiment {embodiment.name!r} has no skeleton edges: the capsule body has nothing to draw"
            )
        style = style or CapsuleStyle()
        traj, camera = prepare_view(embodiment, traj, camera, size, resize_mode, camera_source)
        edges = embodiment.edge_index()
        palette = link_palette(len(edges) + len(embodiment.grippers))
        reach = float(style.reach) if style.reach is not None else body_reach(embodiment)
        _, _, tri = _unit_capsule(int(style.segments))
        n_parts = len(edges) + (len(embodiment.grippers) if style.fingers else 0)
        parts = np.concatenate([np.full(len(tri) * (1 if k < len(edges) else 2), k) for k in range(n_parts)])
        return CapsuleJob(
            embodiment, traj, camera, style, reach, edges, np.ascontiguousarray(palette[parts]), str(device)
        )

    def render_range(
        self, job: CapsuleJob, start: int, stop: int, out: np.ndarray | None, stats: RenderStats | None
    ) -> np.ndarray:
        cam, Pc, uv, folded, faces = _vertices_cv(job, start, stop)
        intr = cam.intrinsics
        if out is None:
            out = np.zeros((stop - start, intr.height, intr.width, 3), np.uint8)
        else:
            out[...] = 0
        draw_frames(Pc, uv, folded, faces, job.face_rgb, intr, job.style.ambient, True, out)
        record_empty(out, start, stats)
        return out


#: the capsule-body renderer (:class:`CapsuleRenderer`)
CAPSULES = CapsuleRenderer()


def iter_capsule_chunks(
    embodiment,
    traj,
    camera: Camera,
    size: tuple[int, int] | None = None,
    *,
    style: CapsuleStyle | None = None,
    resize_mode: str = "crop",
    device="cpu",
    camera_source: str = "<camera>",
    chunk_frames: int = DEFAULT_CHUNK_FRAMES,
    strict: bool = False,
    stats: RenderStats | None = None,
) -> Iterator[np.ndarray]:
    """Render the capsule body of ``traj`` chunk by chunk: yields (n, H, W, 3) uint8, n ≤ chunk_frames.

    Arguments as :func:`oscar_core.render.skeleton_stream.iter_skeleton_chunks`; ``style`` is a :class:`CapsuleStyle`.
    """
    return CAPSULES.iter_chunks(
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


def render_capsule_video(
    embodiment,
    traj,
    camera: Camera,
    size: tuple[int, int] | None = None,
    *,
    style: CapsuleStyle | None = None,
    resize_mode: str = "crop",
    device="cpu",
    camera_source: str = "<camera>",
    chunk_frames: int = 64,
    strict: bool = False,
    stats: RenderStats | None = None,
) -> np.ndarray:
    """The capsule-body condition video of ``traj`` seen by ``camera``: (T, H, W, 3) uint8 RGB on black.

    The counterpart of :func:`oscar_core.render.skeleton_video.render_skeleton_video` (same arguments; ``style`` is a
    :class:`CapsuleStyle`).
    """
    return CAPSULES.render_video(
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
