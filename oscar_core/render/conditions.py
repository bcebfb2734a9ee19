"""The condition videos oscar can render, by name: ``skeleton`` (the paper's), ``mesh`` and ``capsules``.

- ``skeleton``: the paper's 2D kinematic skeleton (:mod:`oscar_core.render.skeleton_stream`);
- ``mesh``: each link's URDF visual geometry (:mod:`oscar_core.render.mesh`);
- ``capsules``: shaded capsules along the skeleton's edges with fingers that open and close
  (:mod:`oscar_core.render.capsules`): a mesh condition for any kinematic tree, with or without visual
  geometry, and the toy world's own robot body.

Every consumer of a condition video (``oscar render``, the batch renderer, the
trainer, rollouts and ``oscar eval run``) picks its renderer here, so a new
condition is added in one place. All go through the VAE and the DiT's PE_s in
the same way (the model's "skeleton" stream carries whichever condition video
its card names).
"""

from __future__ import annotations

from collections.abc import Callable

from ..errors import OscarError

__all__ = ["CONDITIONS", "DEFAULT_CONDITION", "check_condition", "chunk_renderer", "video_renderer",
           "condition_video", "video_condition_of"]

CONDITIONS = ("skeleton", "mesh", "capsules")


def _renderers(name: str) -> tuple[Callable, Callable]:
    """(streaming renderer, whole-video renderer) of a checked condition name (imported on first use)."""
    if name == "mesh":
        from .mesh import iter_mesh_chunks, render_mesh_video

        return iter_mesh_chunks, render_mesh_video
    if name == "capsules":
        from .capsules import iter_capsule_chunks, render_capsule_video

        return iter_capsule_chunks, render_capsule_video
    from .skeleton_stream import iter_skeleton_chunks
    from .skeleton_video import render_skeleton_video

    return iter_skeleton_chunks, render_skeleton_video


DEFAULT_CONDITION = "skeleton"


def check_condition(name, source: str = "condition") -> str:
    """``name`` if it is a known condition, else an :class:`OscarError` naming ``source`` and the choices."""
    if name not in CONDITIONS:
        raise OscarError(f"{source}: expected one of {', '.join(CONDITIONS)}, found {name!r}")
    return name


def video_condition_of(card_condition: str) -> str:
    """The condition video a model whose card says ``card_condition`` is rolled out with: that condition
    when it is a video condition, else the skeleton (models without a video condition ignore it)."""
    return card_condition if card_condition in CONDITIONS else DEFAULT_CONDITION


def chunk_renderer(name: str) -> Callable:
    """The streaming renderer of condition ``name``: ``f(embodiment, traj, camera, size, *, resize_mode,
    device, camera_source, chunk_frames, strict, stats)`` yielding (n, H, W, 3) uint8 chunks."""
    return _renderers(check_condition(name))[0]


def video_renderer(name: str) -> Callable:
    """The whole-video renderer of condition ``name``:
    ``f(embodiment, traj, camera, size, ...)`` → (T, H, W, 3) uint8."""
    return _renderers(check_condition(name))[1]


def condition_video(name: str, embodiment, trajectory, camera, size, *, resize_mode: str = "crop",
                    camera_source: str = "<camera>"):
    """(T, H, W, 3) uint8 condition video ``name`` of ``trajectory`` seen by ``camera`` at ``size`` (width, height)."""
    return video_renderer(name)(embodiment, trajectory, camera, size, resize_mode=resize_mode,
                                camera_source=camera_source)
