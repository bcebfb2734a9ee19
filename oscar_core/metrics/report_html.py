"""Static HTML reports: Jinja2 templates, browser-playable media, relative links.

The pages of ``oscar eval run`` (:mod:`oscar_core.evaluation.html`),
``oscar toyworld eval`` (:mod:`oscar_core.toyworld.html`) and ``oscar data
stats`` (:mod:`oscar_core.data.html`) are rendered from
``oscar_core/templates/*.html.j2`` (autoescaped) and written atomically beside
the JSON they show (this module sits in the metrics layer, beside the plots,
so every layer that writes a report can use it). They open from disk: no server, no network, every media
file referenced by a path relative to the page.

Videos are re-encoded for the browser by :func:`browser_video`: H.264 in
yuv420p MP4 with the index at the front (``+faststart``), which Chromium,
Firefox and Safari play. oscar's lossless outputs (FFV1 ``.mkv``, ``.npy``
arrays, PNG folders) do not play in a browser, so the page never points at
them.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from urllib.parse import quote

import numpy as np

from .._util.atomic import atomic_write_bytes

__all__ = ["TEMPLATES", "render_page", "browser_video", "browser_image", "relative_url", "even_size"]

#: The folder of the report templates (shipped as package data).
TEMPLATES = Path(__file__).parent.parent / "templates"


def _environment():
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(TEMPLATES)),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters["num"] = _num
    env.filters["tojson_attr"] = lambda v: json.dumps(v)
    return env


def _num(value, spec: str = ".3f") -> str:
    """A number for the page: ``format(value, spec)``, ``n/a`` for None."""
    return "n/a" if value is None else format(value, spec)


def render_page(path, template: str, **context) -> Path:
    """Render ``templates/<template>`` with ``context`` into ``path`` (atomically); returns the path.

    Every page also gets ``made`` (:func:`oscar_core._util.provenance.provenance`: date, command, oscar
    version), which the base template shows at the top."""
    from .._util.provenance import provenance

    html = _environment().get_template(template).render(**{"made": provenance(), **context})
    path = Path(path)
    atomic_write_bytes(path, html.encode("utf-8"))
    return path


def relative_url(target, page_dir) -> str:
    """The URL of file ``target`` as seen from a page in folder ``page_dir`` (relative, percent-encoded)."""
    rel = os.path.relpath(Path(target).resolve(), Path(page_dir).resolve())
    return quote(Path(rel).as_posix())


def even_size(frames: np.ndarray) -> np.ndarray:
    """(T, H, W, 3) uint8 frames padded with black to an even height and width (yuv420p needs both even)."""
    t, h, w = frames.shape[:3]
    if h % 2 == 0 and w % 2 == 0:
        return frames
    out = np.zeros((t, h + h % 2, w + w % 2, 3), np.uint8)
    out[:, :h, :w] = frames
    return out


def browser_video(source, dest, *, fps: float | None = None, min_height: int = 128) -> Path:
    """Write ``dest`` (``.mp4``, H.264 yuv420p) from ``source`` unless it is already newer than the source.

    source: a video file, PNG-frame folder or ``.npy`` array
    (:func:`oscar_core.metrics.video.load_video`) or a (T, H, W, 3) uint8
    array (then always written). fps: frames per second of the output
    (default: the source file's, else 10). min_height: frames smaller than
    this are scaled up by an integer factor (nearest neighbour), so a 64 x 64
    toy clip is not a smudge in the browser's 2x layout. Returns ``dest``.
    """
    from ..media.video import VideoWriter

    dest = Path(dest)
    if not isinstance(source, np.ndarray):
        src = Path(source)
        if dest.is_file() and dest.stat().st_mtime >= src.stat().st_mtime:
            return dest
        from .video import load_video

        frames = load_video(src)
        if fps is None:
            fps = _file_fps(src)
    else:
        frames = source
    frames = np.asarray(frames, dtype=np.uint8)
    if frames.ndim != 4 or frames.shape[-1] != 3 or len(frames) == 0:
        raise ValueError(
            f"{source if not isinstance(source, np.ndarray) else 'frames'}: expected (T, H, W, 3) "
            f"frames, found shape {frames.shape}"
        )
    k = max(1, -(-min_height // frames.shape[1]))
    if k > 1:
        frames = frames.repeat(k, axis=1).repeat(k, axis=2)
    dest.parent.mkdir(parents=True, exist_ok=True)
    with VideoWriter(dest, fps or 10.0, crf=20) as writer:
        writer.write(even_size(np.ascontiguousarray(frames)))
    return dest


def browser_image(frame: np.ndarray, dest, *, min_height: int = 96) -> Path:
    """Write one (H, W, 3) uint8 RGB frame as a PNG thumbnail at ``dest`` (integer-upscaled to ``min_height``)."""
    import cv2

    k = max(1, -(-min_height // frame.shape[0]))
    img = np.ascontiguousarray(np.asarray(frame, np.uint8).repeat(k, 0).repeat(k, 1)[..., ::-1])
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise ValueError(f"{dest}: cannot encode a frame of shape {frame.shape} as PNG")
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(dest, buf.tobytes())
    return dest


def _file_fps(path: Path) -> float | None:
    if path.is_file() and path.suffix.lower() in (".mp4", ".mkv", ".mov", ".webm", ".avi"):
        try:
            import av

            with av.open(str(path)) as c:
                rate = c.streams.video[0].average_rate
                return float(rate) if rate else None
        except Exception:  # noqa: BLE001 - the frame rate is a nicety: fall back to the default
            return None
    return None
