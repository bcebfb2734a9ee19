"""The clip-set format of :mod:`oscar_core.train.clips`: its file names (``oscar_clips.json``, ``clips.jsonl``) and
format version, :class:`ClipRecord` (one ``clips.jsonl`` line: id, source, embodiment, T frames, fps, width × height
pixels, (T, G) open/close signal in [0, 1], files by role) and its checks, :class:`Clip` (a clip's contents in
memory), :func:`clip_openness` (a trajectory's open/close signal), the marker file's check, and
:class:`ClipFormatError`, which names the shard, the clip and the field. Re-exported by :mod:`oscar_core.train.clips`.
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import OscarError

__all__ = [
    "CLIPSET_FILE",
    "CLIPSET_FORMAT",
    "SHARD_INDEX",
    "Clip",
    "ClipFormatError",
    "ClipRecord",
    "clip_openness",
]

CLIPSET_FILE = "oscar_clips.json"
CLIPSET_FORMAT = "oscar-clips"
#: 2: a clip set written by a resumable stage (toyworld generate, the latent cache) has its fingerprint.json
#: (oscar_core._util.stage); a set of format 1 may lack it, and is refused by name rather than guessed at
FORMAT_VERSION = 2
SHARD_INDEX = "clips.jsonl"
REQUIRED_FILES = ("rgb", "trajectory", "camera")
OPTIONAL_FILES = ("skeleton", "prompt_embeds", "latents")
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,199}$")
_VIDEO_SUFFIXES = (".mkv", ".mp4")


class ClipFormatError(OscarError, ValueError):
    """A clip set, shard or clip breaks the format; names the shard, the clip and the field."""

    def __init__(self, where, clip, field, expected, found):
        self.where, self.clip, self.field, self.expected, self.found = str(where), clip, field, expected, found
        at = f"{where}: clip {clip!r}" if clip is not None else f"{where}"
        super().__init__(f"{at}: field '{field}': expected {expected}, found {found}")

    def __reduce__(self):
        return (type(self), (self.where, self.clip, self.field, self.expected, self.found))


@dataclass(frozen=True)
class ClipRecord:
    """One clip as listed in a shard's ``clips.jsonl``.

    id: unique in the clip set (letters, digits, ``._-``); source: the dataset
    it came from ("droid", "egodex", "toyworld", …); embodiment: plugin name;
    n_frames: T; fps: frames per second; width, height: RGB frame size, pixels;
    openness: (T, G) open/close signal in [0, 1] per gripper (gripper openness
    for robots, normalised fingertip flexion for hands; G may be 0);
    files: role → path relative to the shard folder (``rgb``, ``trajectory``,
    ``camera`` required; ``skeleton``, ``prompt_embeds``, ``latents`` optional);
    caption: the training caption, or None; task: the dataset's task text, or
    None; meta: free-form provenance (source episode id, frame range, …).
    """

    id: str
    source: str
    embodiment: str
    n_frames: int
    fps: float
    width: int
    height: int
    openness: tuple[tuple[float, ...], ...]
    files: dict[str, str]
    caption: str | None = None
    task: str | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        d = asdict(self)
        d["openness"] = [list(row) for row in self.openness]
        return json.dumps(d, sort_keys=True, separators=(",", ":"))

    @property
    def openness_array(self) -> np.ndarray:
        """(T, G) float64 open/close signal."""
        a = np.asarray(self.openness, dtype=np.float64)
        return a.reshape(self.n_frames, -1)

    @classmethod
    def from_dict(cls, d: Any, where: str) -> ClipRecord:
        """Validate one parsed ``clips.jsonl`` line (``where``: shard and line, for errors)."""
        if not isinstance(d, dict):
            raise ClipFormatError(where, None, "<record>", "a JSON object", type(d).__name__)
        clip = d.get("id")
        if not isinstance(clip, str) or not _ID.match(clip):
            raise ClipFormatError(where, None, "id", "a string of letters, digits and ._- (1-200 chars)", repr(clip))
        known = {f.name for f in fields(cls)}
        required = [f.name for f in fields(cls) if f.name not in ("caption", "task", "meta")]
        missing = [k for k in required if k not in d]
        if missing:
            raise ClipFormatError(where, clip, missing[0], "present", "missing")
        unknown = sorted(set(d) - known)
        if unknown:
            raise ClipFormatError(where, clip, unknown[0], f"one of {sorted(known)}", "an unknown field")
        for k in ("source", "embodiment"):
            if not isinstance(d[k], str) or not d[k]:
                raise ClipFormatError(where, clip, k, "a non-empty string", repr(d[k]))
        for k in ("n_frames", "width", "height"):
            if not isinstance(d[k], int) or isinstance(d[k], bool) or d[k] < 1:
                raise ClipFormatError(where, clip, k, "a positive integer", repr(d[k]))
        if not isinstance(d["fps"], (int, float)) or isinstance(d["fps"], bool) or not d["fps"] > 0:
            raise ClipFormatError(where, clip, "fps", "a positive number", repr(d["fps"]))
        op = d["openness"]
        try:
            arr = np.asarray(op, dtype=np.float64)
        except (TypeError, ValueError):
            raise ClipFormatError(
                where, clip, "openness", "a (T, G) list of numbers", "ragged or non-numeric rows"
            ) from None
        if arr.ndim != 2 or arr.shape[0] != d["n_frames"]:
            raise ClipFormatError(where, clip, "openness", f"shape ({d['n_frames']}, G)", f"shape {arr.shape}")
        if arr.size and (not np.isfinite(arr).all() or arr.min() < 0 or arr.max() > 1):
            raise ClipFormatError(
                where,
                clip,
                "openness",
                "finite values in [0, 1]",
                f"range [{np.nanmin(arr):g}, {np.nanmax(arr):g}]" if np.isfinite(arr).any() else "NaN",
            )
        files = d["files"]
        if not isinstance(files, dict):
            raise ClipFormatError(where, clip, "files", "an object of role -> relative path", type(files).__name__)
        for role in REQUIRED_FILES:
            if role not in files:
                raise ClipFormatError(where, clip, f"files.{role}", "present", "missing")
        for role, rel in files.items():
            if role not in REQUIRED_FILES + OPTIONAL_FILES:
                raise ClipFormatError(
                    where, clip, f"files.{role}", f"a role among {REQUIRED_FILES + OPTIONAL_FILES}", "an unknown role"
                )
            if not isinstance(rel, str) or not rel or rel.startswith("/") or ".." in Path(rel).parts:
                raise ClipFormatError(where, clip, f"files.{role}", "a relative path inside the shard", repr(rel))
        for role in ("rgb", "skeleton"):
            if role in files and Path(files[role]).suffix not in _VIDEO_SUFFIXES:
                raise ClipFormatError(
                    where, clip, f"files.{role}", f"a video ending in {_VIDEO_SUFFIXES}", repr(files[role])
                )
        for k in ("caption", "task"):
            if d.get(k) is not None and not isinstance(d[k], str):
                raise ClipFormatError(where, clip, k, "a string or null", type(d[k]).__name__)
        if not isinstance(d.get("meta", {}), dict):
            raise ClipFormatError(where, clip, "meta", "an object", type(d["meta"]).__name__)
        rows = tuple(tuple(float(v) for v in row) for row in arr)
        return cls(
            id=clip,
            source=d["source"],
            embodiment=d["embodiment"],
            n_frames=d["n_frames"],
            fps=float(d["fps"]),
            width=d["width"],
            height=d["height"],
            openness=rows,
            files=dict(files),
            caption=d.get("caption"),
            task=d.get("task"),
            meta=dict(d.get("meta", {})),
        )


@dataclass(eq=False)
class Clip:
    """A clip's contents in memory.

    rgb: (T, H, W, 3) uint8; trajectory: :class:`~oscar_core.kinematics.trajectory.Trajectory`
    of T frames; camera: :class:`~oscar_core.camera.pinhole.Camera`; skeleton: (T, H, W, 3)
    uint8 or None; prompt_embeds: (L, D) tensor or None; latents: dict with
    ``video``, ``skeleton`` (N, C, t, h, w), ``starts`` (N,) tensors and
    ``window``/``vae``/``width``/``height`` metadata, or None.
    """

    record: ClipRecord
    rgb: np.ndarray | None = None
    trajectory: Any = None
    camera: Any = None
    skeleton: np.ndarray | None = None
    prompt_embeds: Any = None
    latents: dict | None = None


def clip_openness(embodiment, trajectory) -> np.ndarray:
    """(T, G) open/close signal of a trajectory through its embodiment, in [0, 1].

    Robots: gripper openness from the raw gripper signal; embodiments that read
    keypoints (hands) compute it in their ``frames`` (normalised fingertip flexion).
    """
    from ..plugin.openness import trajectory_openness

    return trajectory_openness(embodiment, trajectory)


def _read_marker(path: Path) -> dict:
    try:
        d = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ClipFormatError(path, None, "<file>", "a JSON object", f"unreadable ({exc})") from None
    if not isinstance(d, dict) or d.get("format") != CLIPSET_FORMAT:
        raise ClipFormatError(
            path, None, "format", repr(CLIPSET_FORMAT), repr(d.get("format") if isinstance(d, dict) else d)
        )
    if d.get("format_version") != FORMAT_VERSION:
        raise ClipFormatError(
            path,
            None,
            "format_version",
            f"{FORMAT_VERSION} (a set of another format is made again with the command that made it)",
            repr(d.get("format_version")),
        )
    return d
