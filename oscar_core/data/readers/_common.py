"""Helpers every built-in reader shares: optional imports, local paths, error mapping, video probing.

Nothing here imports h5py, pyarrow or av at module import; each helper
imports what it needs when called.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
from importlib import import_module
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import InputFileError
from ...plugin.reader import EpisodeError, VideoSource

__all__ = ["require", "local_root", "episode_errors", "probe_video", "video_header", "read_json", "finite"]

INSTALL_HINT = 'pip install "oscar-wm[data]"'


def require(module: str, reader: str):
    """Import ``module`` for the reader ``reader``, or raise ImportError naming the extra to install."""
    try:
        return import_module(module)
    except ImportError:
        raise ImportError(
            f"the {reader!r} dataset reader needs the Python package {module.split('.')[0]!r}: {INSTALL_HINT}"
        ) from None


def local_root(source: str, reader: str) -> Path:
    """The local folder a source names (a path or a ``file://`` URL).

    Other fsspec protocols are refused with a message: h5py and PyAV need a
    local (or mounted) file, so copy or mount the dataset first.
    """
    text = str(source)
    if "://" in text:
        protocol, _, rest = text.partition("://")
        if protocol != "file":
            raise ValueError(
                f"{source}: the {reader!r} reader reads local folders (or file:// URLs); "
                f"mount or copy {protocol}:// data first (h5py and PyAV need local files)"
            )
        text = rest
    root = Path(text)
    if not root.is_dir():
        raise ValueError(
            f"{source}: expected a folder holding a {reader!r} dataset, found "
            f"{'a file' if root.exists() else 'nothing'}"
        )
    return root


@contextlib.contextmanager
def episode_errors(episode_id: str, path: Any) -> Iterator[None]:
    """Turn an adapter's InputFileError (or an OSError of ``path``) into an :class:`EpisodeError`."""
    try:
        yield
    except EpisodeError:
        raise
    except InputFileError as e:
        raise EpisodeError(episode_id, e.path, e.field, e.expected, e.found) from None
    except OSError as e:
        raise EpisodeError(
            episode_id,
            getattr(e, "filename", None) or path,
            "<file>",
            "a readable file",
            f"{type(e).__name__}: {e.strerror or e}",
        ) from None


def read_json(path: Path, episode_id: str, what: str) -> Any:
    """A JSON file, or :class:`EpisodeError` naming it (missing or malformed)."""
    if not path.is_file():
        raise EpisodeError(episode_id, path, "<file>", what, "no such file")
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise EpisodeError(episode_id, path, "<file>", f"{what} (JSON)", f"{type(e).__name__}: {e}") from None


def finite(a: Any, episode_id: str, path: Any, field: str, what: str) -> np.ndarray:
    """``a`` as float64, or :class:`EpisodeError` naming the first non-finite value."""
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise EpisodeError(episode_id, path, field, what, f"non-numeric data of type {type(a).__name__}") from None
    bad = ~np.isfinite(arr)
    if bad.any():
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        raise EpisodeError(
            episode_id,
            path,
            field,
            f"{what}, finite values",
            f"{int(bad.sum())} non-finite values (first at index {first})",
        )
    return arr


def probe_video(
    episode_id: str,
    path: Path,
    n_frames: int,
    fps: float | None,
    *,
    start: float = 0.0,
    field: str = "video",
    reader: str = "",
) -> VideoSource:
    """A :class:`VideoSource` for ``n_frames`` frames from ``start`` seconds, after checking the container.

    Demuxes (never decodes) the episode's time range: the file must exist,
    open as a video, and hold a compressed packet for each of the episode's
    ``n_frames`` frames from ``start``. A truncated MP4 (index or frame data
    cut off) fails here, as does a shared file that ends inside the episode.
    fps: the episode's frame rate (None: the video's own).
    """
    path = Path(path)
    with _open_video(episode_id, path, field, reader) as (container, s):
        rate = float(s.average_rate) if s.average_rate else None
        fps = float(fps or rate or 0.0)
        if fps <= 0:
            raise EpisodeError(episode_id, path, field, "a frame rate (from the dataset or the video)", "none")
        have = _count_packets(container, s, start, n_frames, fps)
    if have < n_frames:
        raise EpisodeError(
            episode_id,
            path,
            field,
            f"{n_frames} frames at {fps:g} fps from {start:g} s (one per state frame)",
            f"{max(have, 0)} frames (truncated video?)",
        )
    return VideoSource(str(path), n_frames=int(n_frames), fps=fps, start=float(start))


def _count_packets(container, stream, start: float, n_frames: int, fps: float) -> int:
    """Non-empty packets whose time falls on the episode's frames ``start + i / fps``, i < n_frames."""
    half = 0.5 / fps
    end = start + (n_frames - 0.5) / fps
    if start > half and stream.time_base is not None:
        container.seek(int(max(start - 1.0, 0.0) / stream.time_base), stream=stream, backward=True)
    seen: set[int] = set()
    for packet in container.demux(stream):
        if not packet.size or packet.pts is None or packet.time_base is None:
            continue
        t = float(packet.pts * packet.time_base)
        if t > end + 2.0:  # packets come in decode order: allow for reordering, then stop
            break
        i = int(round((t - start) * fps))
        if 0 <= i < n_frames:
            seen.add(i)
    return len(seen)


def video_header(episode_id: str, path: Path, field: str = "video", reader: str = "") -> tuple[float | None, int, int]:
    """(frame rate or None, width, height) of a video, from its header only; :class:`EpisodeError` if unreadable."""
    with _open_video(episode_id, Path(path), field, reader) as (_, s):
        return (
            float(s.average_rate) if s.average_rate else None,
            int(s.codec_context.width),
            int(s.codec_context.height),
        )


@contextlib.contextmanager
def _open_video(episode_id: str, path: Path, field: str, reader: str):
    """Open a video and yield (container, its first video stream); any failure is an :class:`EpisodeError`."""
    av = require("av", reader or "video")
    if not path.is_file():
        raise EpisodeError(episode_id, path, field, "a video file", "no such file")
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise EpisodeError(episode_id, path, field, "a video stream", "none")
            yield container, container.streams.video[0]
    except EpisodeError:
        raise
    except (av.error.FFmpegError, OSError) as e:
        raise EpisodeError(episode_id, path, field, "a readable video", f"{type(e).__name__}: {e}") from None
