"""The 2D points file: pixel positions of an embodiment's skeleton points on video frames.

One JSON object (docs/formats.md, "Calibration points")::

    {
      "embodiment": "franka",
      "points": [
        {"frame": 0,  "point": "panda_link4", "u": 412.0, "v": 233.5},
        {"frame": 0,  "point": "panda_hand",  "u": 501.3, "v": 310.0},
        {"frame": 40, "point": "panda_link4", "u": 380.8, "v": 240.1}
      ]
    }

``frame``: index into the trajectory (and video), an integer >= 0. ``point``: a
skeleton point's name (``Embodiment.skeleton.links``). ``u``, ``v``: pixels with
pixel centres at integer coordinates (column, row). A point may be missing on any
frame; one entry per (frame, point) at most. ``embodiment`` is optional; when
given it must match the embodiment calibrated.

Only the format is checked here; whether names, frames and pixels fit the
embodiment, the trajectory and the image is checked by
:func:`oscar_core.calibration.pnp.build_correspondences`.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputFileError

__all__ = ["PointsFileError", "PixelPoints", "load_points", "save_points"]

_KEYS = ("embodiment", "points")
_ENTRY_KEYS = ("frame", "point", "u", "v")


class PointsFileError(InputFileError):
    """A bad calibration points file, or points that cannot calibrate a camera (the reason is named)."""


@dataclass(frozen=True)
class PixelPoints:
    """N observed pixel positions.

    frame: (N,) int frame indices; name: N skeleton point names; uv: (N, 2) float
    pixels (u column, v row); embodiment: the file's embodiment name or None;
    source: the file, for error messages.
    """

    frame: np.ndarray
    name: tuple[str, ...]
    uv: np.ndarray
    embodiment: str | None = None
    source: str = "<points>"

    def __len__(self) -> int:
        return len(self.name)

    def to_dict(self) -> dict:
        """The JSON document (:func:`load_points` reads it back)."""
        entries = [
            {"frame": int(f), "point": n, "u": float(u), "v": float(v)}
            for f, n, (u, v) in zip(self.frame, self.name, self.uv)
        ]
        out: dict = {"points": entries}
        if self.embodiment is not None:
            out = {"embodiment": self.embodiment, **out}
        return out


def _short(value) -> str:
    text = json.dumps(value) if not isinstance(value, str) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def parse_points(doc, source: str = "<points>") -> PixelPoints:
    """A :class:`PixelPoints` from the parsed JSON ``doc``; :class:`PointsFileError` naming the field otherwise."""
    if not isinstance(doc, dict):
        raise PointsFileError(source, "<document>", 'a JSON object {"points": [...]}', type(doc).__name__)
    unknown = sorted(set(doc) - set(_KEYS))
    if unknown:
        raise PointsFileError(source, unknown[0], f"only the keys {list(_KEYS)}", f"unknown keys {unknown}")
    if "points" not in doc:
        raise PointsFileError(source, "points", "a list of {frame, point, u, v} entries", "no such key")
    emb = doc.get("embodiment")
    if emb is not None and not isinstance(emb, str):
        raise PointsFileError(source, "embodiment", "a string or null", _short(emb))
    entries = doc["points"]
    if not isinstance(entries, list):
        raise PointsFileError(source, "points", "a list of {frame, point, u, v} entries", type(entries).__name__)
    frames, names, uv, seen = [], [], [], {}
    for i, e in enumerate(entries):
        where = f"points[{i}]"
        if not isinstance(e, dict):
            raise PointsFileError(source, where, "an object {frame, point, u, v}", _short(e))
        missing = [k for k in _ENTRY_KEYS if k not in e]
        extra = sorted(set(e) - set(_ENTRY_KEYS))
        if missing or extra:
            raise PointsFileError(
                source,
                where,
                f"exactly the keys {list(_ENTRY_KEYS)}",
                f"missing {missing}" if missing else f"unknown keys {extra}",
            )
        f = e["frame"]
        if isinstance(f, bool) or not isinstance(f, int) or f < 0:
            raise PointsFileError(source, f"{where}.frame", "a frame index, an integer >= 0", _short(f))
        if not isinstance(e["point"], str) or not e["point"]:
            raise PointsFileError(source, f"{where}.point", "a skeleton point name (a string)", _short(e["point"]))
        for k in ("u", "v"):
            x = e[k]
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                raise PointsFileError(source, f"{where}.{k}", "a finite number of pixels", _short(x))
        key = (f, e["point"])
        if key in seen:
            raise PointsFileError(
                source,
                where,
                "one entry per (frame, point)",
                f"a second entry for frame {f}, point {e['point']!r} (first: points[{seen[key]}])",
            )
        seen[key] = i
        frames.append(f)
        names.append(e["point"])
        uv.append((float(e["u"]), float(e["v"])))
    return PixelPoints(
        np.asarray(frames, dtype=np.int64), tuple(names), np.asarray(uv, dtype=np.float64).reshape(-1, 2), emb, source
    )


def load_points(path: str | os.PathLike) -> PixelPoints:
    """Read a points file (format: module docstring). Raises :class:`PointsFileError` for bad content
    (invalid JSON: line and column), OSError if the file cannot be read."""
    from .._util.json_file import read_json

    return parse_points(read_json(path, PointsFileError), str(Path(path)))


def save_points(points: PixelPoints, path: str | os.PathLike) -> Path:
    """Write ``points`` as JSON atomically (temp file in the same folder, then rename)."""
    from .._util.atomic import atomic_write_bytes

    return atomic_write_bytes(path, (json.dumps(points.to_dict(), indent=1) + "\n").encode("utf-8"))
