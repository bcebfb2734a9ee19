"""The mesh condition: each link's visual geometry drawn through the skeleton's camera.

FK gives every link's pose (the same FK as the skeleton's); the link's
triangles (its URDF ``<visual>`` geometry, or what the plugin's
:meth:`~oscar_core.plugin.embodiment.Embodiment.visual_geometry` returns) are moved
there, projected by exactly the function the skeleton uses
(:func:`oscar_core.camera.projection.project_points_cv`: the same intrinsics, distortion
and convention), shaded flat with a fixed colour per link and a headlight
(:func:`oscar_core.render.mesh_raster.shade_faces`) and drawn with a z-buffer on the same
black canvas (:func:`oscar_core.render.mesh_raster.rasterise_mesh`). The gripper state
shows through the fingers' own geometry, which the finger joints move.

It streams like the skeleton: chunks of frames through FK, projection and
rasterisation, each frame rasterised on its own, so memory does not grow with
the trajectory's length and a frame rendered alone equals the same frame in a video.
The choice of this renderer and its measurements: docs/mesh-condition.md.
"""

from __future__ import annotations

import colorsys
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from ..errors import PluginError
from ..kinematics.visual import VisualGeometry
from .guarded_projection import project_cv, to_camera
from .mesh_raster import CLIP_Z, clip_near, rasterise_mesh, shade_faces
from .renderer import DEFAULT_CHUNK_FRAMES, ChunkedRenderer, RenderStats, prepare_view

__all__ = [
    "MESH",
    "MeshRenderer",
    "MeshJob",
    "MeshStyle",
    "DEFAULT_SIMPLIFY",
    "link_palette",
    "mesh_geometry",
    "mesh_vertices",
    "iter_mesh_chunks",
    "render_mesh_video",
]

#: default vertex-clustering cell, metres (docs/mesh-condition.md: silhouette IoU against the full meshes)
DEFAULT_SIMPLIFY = 0.008


@dataclass(frozen=True)
class MeshStyle:
    """How the mesh condition looks.

    simplify: vertex-clustering cell in metres (None: the meshes as given);
    ambient: light on faces seen edge-on, 0–1 (faces facing the camera get 1);
    cull_back: skip triangles facing away from the camera (half the work; right for
    closed meshes wound counter-clockwise seen from outside, as URDF meshes and the
    primitives here are: docs/mesh-condition.md measures it on franka).
    Link colours: :func:`link_palette`, fixed per link.
    """

    simplify: float | None = DEFAULT_SIMPLIFY
    ambient: float = 0.3
    cull_back: bool = True


def link_palette(count: int) -> np.ndarray:
    """(count, 3) uint8 RGB: hues spread by the golden angle, so neighbouring links differ."""
    rgb = [colorsys.hsv_to_rgb((0.08 + i * 0.381966) % 1.0, 0.55, 1.0) for i in range(count)]
    return np.round(np.array(rgb, dtype=np.float64).reshape(-1, 3) * 255).astype(np.uint8)


@dataclass(frozen=True)
class _Mesh:
    """One embodiment's triangles ready to draw: links (L,), vertices (V, 3) in their link's
    frame, vertex_link (V,) index into links, faces (F, 3), face_rgb (F, 3) uint8."""

    links: tuple[str, ...]
    vertices: np.ndarray
    vertex_link: np.ndarray
    faces: np.ndarray
    face_rgb: np.ndarray


def mesh_geometry(embodiment, simplify: float | None = DEFAULT_SIMPLIFY) -> VisualGeometry:
    """The embodiment's visual geometry, checked and simplified (cached on the embodiment).

    Raises :class:`PluginError` when the plugin gives none, returns something
    other than a :class:`VisualGeometry`, or names links its kinematic tree lacks.
    """
    cache = embodiment.__dict__.setdefault("_mesh_geometry", {})
    if simplify in cache:
        return cache[simplify]
    geo = cache.get("full")
    if geo is None:
        geo = embodiment.visual_geometry()
        if not isinstance(geo, VisualGeometry):
            raise PluginError(
                f"embodiment {embodiment.name!r}: visual_geometry() must return a "
                f"oscar_core.kinematics.visual.VisualGeometry, found {type(geo).__name__}"
            )
        if not geo.links or geo.face_count == 0:
            raise PluginError(
                f"embodiment {embodiment.name!r} has no visual geometry ({geo.source} gives no "
                "triangles); the mesh condition needs <visual> elements in its URDF or an override "
                "of Embodiment.visual_geometry"
            )
        known = set(embodiment.tree.links)
        unknown = [n for n in geo.link_names if n not in known]
        if unknown:
            raise PluginError(
                f"embodiment {embodiment.name!r}: visual geometry ({geo.source}) names links "
                f"{unknown} that its kinematic tree does not have"
            )
        cache["full"] = geo
    out = geo if simplify is None else geo.simplified(simplify)
    cache[simplify] = out
    return out


def _pack(geo: VisualGeometry) -> _Mesh:
    names = tuple(dict.fromkeys(geo.link_names))
    at = {n: i for i, n in enumerate(names)}
    palette = link_palette(len(names))
    verts, vlink, faces, rgb = [], [], [], []
    offset = 0
    for g in geo.links:
        verts.append(g.vertices)
        vlink.append(np.full(len(g.vertices), at[g.link]))
        faces.append(g.faces + offset)
        rgb.append(np.broadcast_to(palette[at[g.link]], (len(g.faces), 3)))
        offset += len(g.vertices)
    return _Mesh(
        names,
        np.concatenate(verts),
        np.concatenate(vlink),
        np.concatenate(faces),
        np.ascontiguousarray(np.concatenate(rgb)),
    )


@dataclass(frozen=True)
class MeshJob:
    """A prepared mesh render: the checked trajectory, the sized camera, the style and the packed link meshes."""

    embodiment: object
    traj: object
    camera: Camera
    style: MeshStyle
    device: str
    mesh: _Mesh


def _world_vertices(mesh: _Mesh, poses: np.ndarray) -> np.ndarray:
    """(T, V, 3) world vertices from link poses (T, L, 4, 4)."""
    T = poses.shape[0]
    out = np.empty((T, len(mesh.vertices), 3))
    for i in range(len(mesh.links)):
        sel = mesh.vertex_link == i
        R, t = poses[:, i, :3, :3], poses[:, i, :3, 3]
        out[:, sel] = mesh.vertices[sel] @ np.swapaxes(R, -1, -2) + t[:, None, :]
    return out


def vertices_cv(job: MeshJob, start: int, stop: int):
    """Frames start:stop → (camera slice, (n, V, 3) camera-frame vertices, (n, V, 2) pixels, (n, V) folded)."""
    cam = job.camera.time_slice(start, stop)
    sub = job.traj.time_slice(start, stop)
    emb = job.embodiment
    mount = [cam.mount_link] if cam.mount_link else []
    links = list(job.mesh.links) + mount
    # the FK the skeleton's frames() uses (NumPy on the CPU, the plugin's own fk otherwise)
    poses = emb._link_poses(emb.full_configuration(sub), sub.base_pose, links, job.device)
    M = cam.world_to_cv(poses[:, -1] if mount else None)
    Pc = to_camera(_world_vertices(job.mesh, poses[:, : len(job.mesh.links)]), M)
    # the skeleton's projection; folded: beyond the lens model's valid radius
    uv, folded = project_cv(Pc, cam.intrinsics)
    return cam, Pc, uv, folded


def mesh_vertices(
    embodiment,
    traj,
    camera: Camera,
    size: tuple[int, int] | None = None,
    *,
    style: MeshStyle | None = None,
    resize_mode: str = "crop",
    device="cpu",
    camera_source: str = "<camera>",
) -> tuple[np.ndarray, np.ndarray]:
    """Where the renderer puts every vertex: (T, V, 2) pixels and (T, V) depth in metres.

    Vertices are those of :func:`mesh_geometry` (``style.simplify``), links in
    its order. The renderer draws exactly these positions.
    """
    job = MESH.prepare(
        embodiment, traj, camera, size, style=style, resize_mode=resize_mode, device=device, camera_source=camera_source
    )
    _, Pc, uv, _ = vertices_cv(job, 0, len(job.traj))
    return uv, Pc[..., 2]


def draw_frames(
    Pc: np.ndarray,
    uv: np.ndarray,
    folded: np.ndarray,
    faces: np.ndarray,
    face_rgb: np.ndarray,
    intr,
    ambient: float,
    cull_back: bool,
    out: np.ndarray,
) -> np.ndarray:
    """Rasterise n frames of one triangle set into ``out`` (n, H, W, 3) uint8 (drawn over, not cleared).

    Pc: (n, V, 3) camera-frame vertices, metres; uv: (n, V, 2) their pixels; folded: (n, V) bool,
    True where the lens model is not to be trusted; faces: (F, 3); face_rgb: (F, 3) uint8 base
    colours, shaded flat with a headlight (:func:`~oscar_core.render.mesh_raster.shade_faces`). Triangles
    reaching behind the camera are cut at the near plane first. Shared by every renderer of
    triangles (link meshes, :mod:`oscar_core.render.capsules`).
    """
    size = (intr.width, intr.height)
    for i in range(len(Pc)):
        P, f, src, uv_i, ok = Pc[i], faces, None, uv[i], ~folded[i]
        if not (P[:, 2] > CLIP_Z).all():  # some geometry at or behind the near plane: cut the triangles there
            P, f, src = clip_near(P, f)
            extra, extra_folded = project_cv(P[len(Pc[i]) :], intr)
            uv_i = np.concatenate([uv_i, extra])
            ok = np.concatenate([ok, ~extra_folded])

        def shade(kept, P=P, f=f, src=src):
            base = face_rgb[kept if src is None else src[kept]]
            return shade_faces(P, f[kept], base, ambient)

        rasterise_mesh(uv_i, P[:, 2], f, shade, size, out[i], usable=ok, cull_back=cull_back)
    return out


def record_empty(out: np.ndarray, start: int, stats: RenderStats | None) -> None:
    """Count the frames of ``out`` (n, H, W, 3) and record those with nothing drawn (frame numbers from ``start``)."""
    if stats is not None:
        n = len(out)
        seen = out.reshape(n, -1).any(axis=1)
        stats.frames += n
        stats.empty_frames.extend((start + np.flatnonzero(~seen)).tolist())


class MeshRenderer(ChunkedRenderer):
    """Each link's visual geometry, flat-shaded with a colour per link, on black."""

    name = "mesh"
    sees_nothing_of = "of the robot's geometry"
    video_chunk_frames = 64

    def prepare(
        self,
        embodiment,
        traj,
        camera: Camera,
        size,
        *,
        style: MeshStyle | None,
        resize_mode: str,
        device,
        camera_source: str,
    ) -> MeshJob:
        """Also raises :class:`PluginError` for an embodiment without a kinematic tree."""
        if not embodiment.uses_kinematic_tree():
            raise PluginError(
                f"embodiment {embodiment.name!r} computes its points itself (no kinematic tree); "
                "the mesh condition needs link poses and visual geometry, which it does not have"
            )
        style = style or MeshStyle()
        mesh = _pack(mesh_geometry(embodiment, style.simplify))
        traj, camera = prepare_view(embodiment, traj, camera, size, resize_mode, camera_source)
        return MeshJob(embodiment, traj, camera, style, str(device), mesh)

    def render_range(
        self, job: MeshJob, start: int, stop: int, out: np.ndarray | None, stats: RenderStats | None
    ) -> np.ndarray:
        cam, Pc, uv, folded = vertices_cv(job, start, stop)
        intr = cam.intrinsics
        if out is None:
            out = np.zeros((stop - start, intr.height, intr.width, 3), np.uint8)
        else:
            out[...] = 0
        draw_frames(
            Pc, uv, folded, job.mesh.faces, job.mesh.face_rgb, intr, job.style.ambient, job.style.cull_back, out
        )
        record_empty(out, start, stats)
        return out


#: the mesh renderer (:class:`MeshRenderer`)
MESH = MeshRenderer()


def iter_mesh_chunks(
    embodiment,
    traj,
    camera: Camera,
    size: tuple[int, int] | None = None,
    *,
    style: MeshStyle | None = None,
    resize_mode: str = "crop",
    device="cpu",
    camera_source: str = "<camera>",
    chunk_frames: int = DEFAULT_CHUNK_FRAMES,
    strict: bool = False,
    stats: RenderStats | None = None,
) -> Iterator[np.ndarray]:
    """Render the mesh condition of ``traj`` chunk by chunk: yields (n, H, W, 3) uint8, n ≤ chunk_frames.

    Arguments as :func:`oscar_core.render.skeleton_stream.iter_skeleton_chunks`; ``style`` is a
    :class:`MeshStyle`. Frames where no triangle lands in the image give one
    :class:`~oscar_core.render.renderer.EmptyViewWarning` at the end (``strict``:
    :class:`~oscar_core.render.renderer.EmptyViewError` at once).
    """
    return MESH.iter_chunks(
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


def render_mesh_video(
    embodiment,
    traj,
    camera: Camera,
    size: tuple[int, int] | None = None,
    *,
    style: MeshStyle | None = None,
    resize_mode: str = "crop",
    device="cpu",
    camera_source: str = "<camera>",
    chunk_frames: int = 64,
    strict: bool = False,
    stats: RenderStats | None = None,
) -> np.ndarray:
    """The mesh condition video of ``traj`` seen by ``camera``: (T, H, W, 3) uint8 RGB on black.

    The counterpart of :func:`oscar_core.render.skeleton_video.render_skeleton_video` (same
    arguments; ``style`` is a :class:`MeshStyle`). For long videos use
    :func:`iter_mesh_chunks`. Raises :class:`PluginError` for an embodiment
    without visual geometry.
    """
    return MESH.render_video(
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
