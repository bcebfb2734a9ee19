"""The condition-renderer protocol and the chunk loop its implementations share.

A condition renderer (:class:`ConditionRenderer`) turns a trajectory seen by a
camera into a condition video in four calls: :meth:`~ConditionRenderer.prepare`
checks the inputs and builds a job once (the camera sized to the output),
:meth:`~ConditionRenderer.render_range` draws any range of frames of that job,
:meth:`~ConditionRenderer.iter_chunks` yields the video chunk by chunk, and
:meth:`~ConditionRenderer.render_video` returns it whole. The skeleton
(:mod:`oscar_core.render.skeleton_stream`), the mesh (:mod:`oscar_core.render.mesh`) and the
capsule body (:mod:`oscar_core.render.capsules`) implement it by subclassing
:class:`ChunkedRenderer`, which writes the last two once from the first two;
:mod:`oscar_core.render.conditions` names them.

Frames in which the camera sees nothing of the robot are counted in a
:class:`RenderStats` and reported once, by frame number, as an
:class:`EmptyViewWarning` (``strict``: an :class:`EmptyViewError` as soon as a chunk has one).
Images are (n, H, W, 3) uint8 RGB; sizes are (width, height) pixels.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ..errors import OscarError

__all__ = [
    "DEFAULT_CHUNK_FRAMES",
    "EmptyViewWarning",
    "EmptyViewError",
    "RenderStats",
    "format_frames",
    "RenderJob",
    "ConditionRenderer",
    "ChunkedRenderer",
    "prepare_view",
]

DEFAULT_CHUNK_FRAMES = 16


class EmptyViewWarning(UserWarning):
    """The camera sees nothing of the robot in some frames; the video is written anyway."""


class EmptyViewError(OscarError):
    """``strict``: the camera sees nothing of the robot in some frames."""


@dataclass
class RenderStats:
    """What one render saw: ``frames`` rendered, ``empty_frames`` (frame indices where the camera sees nothing of
    the robot: for the skeleton every point behind the camera or outside the image, for a mesh no pixel drawn)."""

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


def prepare_view(embodiment, traj, camera, size, resize_mode: str, camera_source: str):
    """The checks every condition starts with: (checked trajectory, camera sized to ``size``).

    The trajectory is checked against the embodiment, the camera against the embodiment and (a camera with one
    extrinsic per frame) the trajectory's length; ``size`` (width, height) other than the calibration's resizes
    the camera (``resize_mode`` "crop" or "stretch"); None keeps it.
    """
    traj = embodiment.check_trajectory(traj)
    embodiment.check_camera(camera, camera_source)
    camera.check_frames(len(traj), camera_source)  # a per-frame camera needs one extrinsic per trajectory frame
    if size is not None and (size[0], size[1]) != (camera.intrinsics.width, camera.intrinsics.height):
        camera = camera.resized(size[0], size[1], mode=resize_mode)
    return traj, camera


class RenderJob(Protocol):
    """What the chunk loop needs of a prepared job: the checked trajectory and the sized camera."""

    traj: Any
    camera: Any


class ConditionRenderer(Protocol):
    """A condition video renderer. ``name`` is its condition's name (:mod:`oscar_core.render.conditions`)."""

    name: str

    def prepare(
        self, embodiment, traj, camera, size, *, style, resize_mode: str, device, camera_source: str
    ) -> RenderJob:
        """Check the inputs and build what every frame range needs (raises before any frame is drawn)."""

    def render_range(
        self, job: RenderJob, start: int, stop: int, out: np.ndarray | None, stats: RenderStats | None
    ) -> np.ndarray:
        """Frames ``start:stop`` of ``job`` → (n, H, W, 3) uint8 (into ``out`` when given); empty frames are
        recorded in ``stats``."""

    def iter_chunks(
        self,
        embodiment,
        traj,
        camera,
        size: tuple[int, int] | None = None,
        *,
        style=None,
        resize_mode: str = "crop",
        device="cpu",
        camera_source: str = "<camera>",
        chunk_frames: int = DEFAULT_CHUNK_FRAMES,
        strict: bool = False,
        stats: RenderStats | None = None,
    ) -> Iterator[np.ndarray]:
        """The video chunk by chunk: (n, H, W, 3) uint8 arrays, n ≤ chunk_frames, each a fresh array."""

    def render_video(
        self,
        embodiment,
        traj,
        camera,
        size: tuple[int, int] | None = None,
        *,
        style=None,
        resize_mode: str = "crop",
        device="cpu",
        camera_source: str = "<camera>",
        chunk_frames: int | None = None,
        strict: bool = False,
        stats: RenderStats | None = None,
    ) -> np.ndarray:
        """The whole video as one (T, H, W, 3) uint8 array."""


class ChunkedRenderer:
    """:class:`ConditionRenderer`'s chunk loop, written once: a subclass gives ``name``, ``prepare``,
    ``render_range`` and the wording of its empty frames (``sees_nothing_of``).

    video_chunk_frames: frames per range :meth:`render_video` draws at once (the whole video is one array anyway;
    a larger range amortises per-call work, a smaller one bounds the renderer's temporaries).
    """

    name: str = ""
    sees_nothing_of: str = "of the robot"
    video_chunk_frames: int = 64

    def prepare(self, embodiment, traj, camera, size, *, style, resize_mode, device, camera_source):
        raise NotImplementedError

    def render_range(self, job, start: int, stop: int, out: np.ndarray | None, stats: RenderStats | None) -> np.ndarray:
        raise NotImplementedError

    def empty_message(self, source: str, empty: list[int], total: int) -> str:
        """The sentence of an :class:`EmptyViewWarning` / :class:`EmptyViewError` naming the empty frames."""
        return (
            f"{source}: the camera sees nothing {self.sees_nothing_of} in {len(empty)} of {total} frames: "
            f"{format_frames(empty)}"
        )

    def iter_chunks(
        self,
        embodiment,
        traj,
        camera,
        size: tuple[int, int] | None = None,
        *,
        style=None,
        resize_mode: str = "crop",
        device="cpu",
        camera_source: str = "<camera>",
        chunk_frames: int = DEFAULT_CHUNK_FRAMES,
        strict: bool = False,
        stats: RenderStats | None = None,
    ) -> Iterator[np.ndarray]:
        """Render chunk by chunk: yields (n, H, W, 3) uint8 RGB arrays, n ≤ chunk_frames, each a fresh array.

        size: output (width, height) pixels (None: the calibration's size; ``resize_mode`` "crop": centre crop
        to the aspect ratio, then scale; "stretch"). chunk_frames: frames per chunk (memory is about
        chunk_frames × W × H × 3 bytes plus the writer's). After the last chunk, frames where the camera sees
        nothing of the robot give one :class:`EmptyViewWarning` naming them; ``strict`` raises
        :class:`EmptyViewError` instead, as soon as a chunk has such a frame. stats: optional
        :class:`RenderStats` filled as chunks are rendered. The inputs are checked when the first chunk is
        asked for.
        """
        if chunk_frames < 1:
            raise ValueError(f"chunk_frames: expected a positive number of frames, found {chunk_frames}")
        job = self.prepare(
            embodiment,
            traj,
            camera,
            size,
            style=style,
            resize_mode=resize_mode,
            device=device,
            camera_source=camera_source,
        )
        stats = stats if stats is not None else RenderStats()
        total = len(job.traj)
        for start in range(0, total, chunk_frames):
            before = len(stats.empty_frames)
            chunk = self.render_range(job, start, min(total, start + chunk_frames), None, stats)
            if strict and len(stats.empty_frames) > before:
                raise EmptyViewError(
                    self.empty_message(camera_source, stats.empty_frames[before:], total) + " (strict)"
                )
            yield chunk
        if stats.empty_frames:
            warnings.warn(self.empty_message(camera_source, stats.empty_frames, total), EmptyViewWarning, stacklevel=2)

    def render_video(
        self,
        embodiment,
        traj,
        camera,
        size: tuple[int, int] | None = None,
        *,
        style=None,
        resize_mode: str = "crop",
        device="cpu",
        camera_source: str = "<camera>",
        chunk_frames: int | None = None,
        strict: bool = False,
        stats: RenderStats | None = None,
    ) -> np.ndarray:
        """The whole video as one (T, H, W, 3) uint8 RGB array on black, drawn range by range into it
        (``chunk_frames`` frames at a time, default :attr:`video_chunk_frames`); arguments as
        :meth:`iter_chunks`. Empty frames give one :class:`EmptyViewWarning` at the end (``strict``:
        :class:`EmptyViewError`)."""
        job = self.prepare(
            embodiment,
            traj,
            camera,
            size,
            style=style,
            resize_mode=resize_mode,
            device=device,
            camera_source=camera_source,
        )
        stats = stats if stats is not None else RenderStats()
        intr = job.camera.intrinsics
        total = len(job.traj)
        step = int(chunk_frames or self.video_chunk_frames)
        out = np.empty((total, intr.height, intr.width, 3), np.uint8)
        for start in range(0, total, step):
            stop = min(total, start + step)
            self.render_range(job, start, stop, out[start:stop], stats)
        if stats.empty_frames:
            text = self.empty_message(camera_source, stats.empty_frames, total)
            if strict:
                raise EmptyViewError(text + " (strict)")
            warnings.warn(text, EmptyViewWarning, stacklevel=3)
        return out
