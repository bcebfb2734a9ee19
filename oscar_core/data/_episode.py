"""Load a manifest row's episode in any worker process (registry built once per process)."""

from __future__ import annotations

import functools
import json
from typing import Any

from ..errors import OscarError
from .manifest import row_to_ref

__all__ = ["registry", "load_row", "reason_of", "camera_at_video_size"]


@functools.lru_cache(maxsize=4)
def registry(plugin_paths: tuple[str, ...] = ()):
    """The embodiment + reader registry of this process (plugin files added by ``--plugin``)."""
    from ..plugin.registry import Registry

    return Registry(plugin_paths=plugin_paths)


def load_row(row: dict[str, Any], plugin_paths: tuple[str, ...] = ()):
    """(episode, embodiment) of a manifest row, through its reader."""
    reg = registry(tuple(plugin_paths))
    options = row.get("reader_options")  # JSON of ingest's --reader-option values (absent in older manifests)
    if options:
        from .reader_options import check_reader_options

        entry = reg.reader_entries.get(row["reader"])
        options = check_reader_options(entry.cls, json.loads(options)) if entry is not None else None
    reader = reg.get_reader(row["reader"], options or None)
    ep = reader.load_episode(row_to_ref(row), reg)
    return ep, reg.get(row["embodiment"])


def camera_at_video_size(camera, width: int | None, height: int | None):
    """The calibration rescaled to the video's frame size (centre crop to its aspect ratio, as ``oscar render``)."""
    if width and height and (camera.intrinsics.width, camera.intrinsics.height) != (width, height):
        return camera.resized(int(width), int(height), mode="crop")
    return camera


def reason_of(exc: BaseException) -> str:
    """One line naming an episode-level error (the reader's message already names file and field)."""
    msg = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {msg}"[:500]


# errors that mean "this episode is broken" (bad input, an embodiment no plugin provides), not "the pipeline has a bug"
EPISODE_ERRORS: tuple[type[BaseException], ...] = (OscarError, ValueError, OSError)
