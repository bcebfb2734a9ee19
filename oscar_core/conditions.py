"""The condition videos oscar can render, by name: ``skeleton`` (the paper's) and ``mesh``.

Every consumer of a condition video (``oscar render``, the batch renderer, the
trainer, rollouts and ``oscar eval run``) picks its renderer here, so a new
condition is added in one place. Both go through the VAE and the DiT's PE_s in
the same way (the model's "skeleton" stream carries whichever condition video
its card names).
"""

from __future__ import annotations

from typing import Callable

from .errors import OscarError

__all__ = ["CONDITIONS", "DEFAULT_CONDITION", "check_condition", "chunk_renderer", "video_renderer",
           "condition_video"]

CONDITIONS = ("skeleton", "mesh")
DEFAULT_CONDITION = "skeleton"


def check_condition(name, source: str = "condition") -> str:
    """``name`` if it is a known condition, else an :class:`OscarError` naming ``source`` and the choices."""
    if name not in CONDITIONS:
        raise OscarError(f"{source}: expected one of {', '.join(CONDITIONS)}, found {name!r}")
    return name


def chunk_renderer(name: str) -> Callable:
    """The streaming renderer of condition ``name``: ``f(embodiment, traj, camera, size, *, resize_mode,
    device, camera_source, chunk_frames, strict, stats)`` yielding (n, H, W, 3) uint8 chunks."""
    if check_condition(name) == "mesh":
        from .mesh_render import iter_mesh_chunks

        return iter_mesh_chunks
    from .render_stream import iter_skeleton_chunks

    return iter_skeleton_chunks


def video_renderer(name: str) -> Callable:
    """The whole-video renderer of condition ``name``:
    ``f(embodiment, traj, camera, size, ...)`` → (T, H, W, 3) uint8."""
    if check_condition(name) == "mesh":
        from .mesh_render import render_mesh_video

        return render_mesh_video
    from .pipeline import render_skeleton_video

    return render_skeleton_video


def condition_video(name: str, embodiment, trajectory, camera, size, *, resize_mode: str = "crop",
                    camera_source: str = "<camera>"):
    """(T, H, W, 3) uint8 condition video ``name`` of ``trajectory`` seen by ``camera`` at ``size`` (width, height)."""
    return video_renderer(name)(embodiment, trajectory, camera, size, resize_mode=resize_mode,
                                camera_source=camera_source)
