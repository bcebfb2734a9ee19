"""The dataset-reader contract: how a source dataset's files become oscar episodes.

A reader is a class registered through the ``oscar_register_readers`` hook
(like embodiments). It does two things:

* :meth:`Reader.list_episodes` walks a source (a local folder or an fsspec
  URL) and yields one cheap :class:`EpisodeRef` per episode — from metadata
  only, never decoding a video — which ``oscar data ingest`` writes to the
  manifest;
* :meth:`Reader.load_episode` turns one ref into an :class:`Episode`: an
  oscar :class:`~oscar_core.kinematics.trajectory.Trajectory` and
  :class:`~oscar_core.camera.pinhole.Camera` (through the embodiment's dataset
  adapters) and a :class:`VideoSource` that decodes the episode's frames on
  demand.

Readers raise :class:`EpisodeError` for a broken episode (missing field, NaN
states, lengths that disagree, unreadable video); the pipeline records the
episode as rejected with that reason and goes on.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from ..errors import OscarError

__all__ = ["EpisodeError", "EpisodeRef", "Episode", "VideoSource", "Reader"]


class EpisodeError(OscarError, ValueError):
    """One episode cannot be read; names the episode, the file, the field, what was expected and found."""

    def __init__(self, episode_id, path, field, expected, found):
        self.episode_id, self.path, self.field, self.expected, self.found = (
            episode_id,
            str(path),
            field,
            expected,
            found,
        )
        super().__init__(f"episode {episode_id!r}: {path}: field '{field}': expected {expected}, found {found}")

    def __reduce__(self):
        return (type(self), (self.episode_id, self.path, self.field, self.expected, self.found))


@dataclass(frozen=True)
class EpisodeRef:
    """A pointer to one episode of a source dataset, as listed in the manifest.

    episode_id: unique within a run, ``"<source>/<native id>"``; source: the
    dataset's name (``droid``, ``rh20t_cfg5``, ``egodex``, …); reader: the
    reader's name; embodiment: the plugin that draws it; paths: role → path or
    URL of the files that hold it (``video``, ``states``, ``calibration``, …,
    the reader's own roles); n_frames, fps: from metadata when known without
    decoding (else None); task: the dataset's task text; cameras: the camera
    names available; meta: reader-specific small values (JSON-serialisable).
    """

    episode_id: str
    source: str
    reader: str
    embodiment: str
    paths: dict[str, str]
    n_frames: int | None = None
    fps: float | None = None
    task: str | None = None
    cameras: tuple[str, ...] = ()
    meta: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class VideoSource:
    """Where one episode's frames are: a video file, optionally a time range of a shared one.

    path: local path of the video (LeRobot v3 stores many episodes per MP4);
    start: time of the episode's first frame in the file, seconds;
    n_frames: frames of the episode; fps: its frame rate.
    """

    path: str
    n_frames: int
    fps: float
    start: float = 0.0

    def read(self, indices: Sequence[int] | None = None) -> np.ndarray:
        """(N, H, W, 3) uint8 RGB frames at ``indices`` (episode frame numbers; None: all).

        Seeks to the episode's start and decodes forward; a frame is the one
        whose timestamp is nearest ``start + i / fps``. Raises ValueError naming
        the file when the video is unreadable or ends early.
        """
        import av

        want = list(range(self.n_frames)) if indices is None else [int(i) for i in indices]
        if any(i < 0 or i >= self.n_frames for i in want):
            raise ValueError(
                f"{self.path}: frame indices must lie in [0, {self.n_frames}), found "
                f"{[i for i in want if i < 0 or i >= self.n_frames][:5]}"
            )
        if not want:
            return np.zeros((0, 0, 0, 3), np.uint8)
        order = sorted(set(want))
        got: dict[int, np.ndarray] = {}
        half = 0.5 / self.fps
        try:
            with av.open(self.path) as container:
                stream = container.streams.video[0]
                first_t = self.start + order[0] / self.fps
                if first_t > half and stream.time_base is not None:
                    container.seek(int(max(first_t - 1.0, 0.0) / stream.time_base), stream=stream, backward=True)
                k = 0
                for frame in container.decode(stream):
                    if frame.time is None:
                        continue
                    idx = int(round((float(frame.time) - self.start) * self.fps))
                    if idx < order[k]:
                        continue
                    while k < len(order) and order[k] < idx:  # a frame missing from the file
                        k += 1
                    if k < len(order) and order[k] == idx:
                        got[idx] = frame.to_ndarray(format="rgb24")
                        k += 1
                    if k >= len(order):
                        break
        except av.error.FFmpegError as exc:
            raise ValueError(f"{self.path}: not a readable video ({exc})") from None
        missing = [i for i in order if i not in got]
        if missing:
            raise ValueError(
                f"{self.path}: expected {self.n_frames} frames from {self.start:g} s at {self.fps:g} fps, "
                f"frames {missing[:5]}{'…' if len(missing) > 5 else ''} are missing (truncated video?)"
            )
        return np.stack([got[i] for i in want])


@dataclass(eq=False)
class Episode:
    """One loaded episode.

    ref: its manifest row; trajectory: T frames in the embodiment's joint order
    and units; camera: the calibration of the camera ``camera_name``;
    video: its frames, or None when the dataset has no video; task: text.
    """

    ref: EpisodeRef
    trajectory: Any
    camera: Any
    camera_name: str
    video: VideoSource | None
    task: str | None = None

    @property
    def n_frames(self) -> int:
        return len(self.trajectory)


class Reader:
    """Base class of dataset readers. Subclasses set ``name`` and implement both methods.

    name: unique reader name (``--reader NAME``); description: one line;
    embodiments: the plugins it produces episodes for.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    embodiments: ClassVar[tuple[str, ...]] = ()

    def list_episodes(self, source: str) -> Iterator[EpisodeRef]:
        """Yield one ref per episode found under ``source`` (a folder or an fsspec URL), cheaply."""
        raise NotImplementedError(f"{type(self).__name__}.list_episodes")

    def load_episode(self, ref: EpisodeRef, registry=None) -> Episode:
        """Read one episode; raise :class:`EpisodeError` when it is broken.

        registry: the embodiment registry to build trajectories and cameras
        with (None: the default registry).
        """
        raise NotImplementedError(f"{type(self).__name__}.load_episode")

    @classmethod
    def class_problems(cls) -> list[str]:
        """What breaks the contract (empty when the class is usable)."""
        problems = []
        if not isinstance(cls.name, str) or not cls.name:
            problems.append("declares no `name`")
        for meth in ("list_episodes", "load_episode"):
            if getattr(cls, meth) is getattr(Reader, meth):
                problems.append(f"does not implement `{meth}`")
        return problems
