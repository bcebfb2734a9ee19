"""Frames for oscar's VLM judges: uniform sampling, loading, downscaling, side-by-side layout, image encoding
and content hashes of the videos (the cache keys' first part).

Frames
------
``n_frames`` (default 32 for the success judge, 16 per rollout for the
pairwise judge) are sampled uniformly over the clip with
``round(linspace(0, T − 1, n))``, so the first and the last frame are always
included (``n = 1`` sends the last frame: the end state decides success). A
clip with fewer than ``n_frames`` frames sends **all** its frames (the
verdict records ``frames_sent`` and ``frames_total``). A frame whose longer
side exceeds ``max_side`` (default 512, so the paper's native 512×288 rollouts
go unchanged) is downscaled with area interpolation, keeping its aspect ratio;
smaller frames are never upscaled. Frames are encoded as JPEG (quality 90) or
PNG and sent as base64 ``data:`` URLs in ``image_url`` content parts.
"""

from __future__ import annotations

import base64
import hashlib
import os
from pathlib import Path

import numpy as np

from .common import MetricInputError

__all__ = ["DEFAULT_MAX_SIDE", "sample_frame_indices"]

#: Longer side, in pixels, above which frames are downscaled (the paper's rollouts are 512×288).
DEFAULT_MAX_SIDE = 512
_SEPARATOR_PX = 8


# --------------------------------------------------------------------------- #
# frames
# --------------------------------------------------------------------------- #
def sample_frame_indices(total: int, n: int) -> np.ndarray:
    """Indices of ``n`` frames sampled uniformly from ``total``: ``round(linspace(0, total − 1, n))``.

    The first and last frame are included for n ≥ 2, the indices are distinct
    and increasing; ``n ≥ total`` returns every frame; ``n = 1`` returns the last frame.
    """
    if total < 1:
        raise MetricInputError("video", "frames", "at least 1 frame", f"{total} frames")
    if n < 1:
        raise MetricInputError("n_frames", "value", "an integer >= 1", n)
    if n >= total:
        return np.arange(total)
    if n == 1:
        return np.array([total - 1])
    return np.rint(np.linspace(0, total - 1, n)).astype(np.int64)


def _to_uint8(video) -> np.ndarray:
    if hasattr(video, "detach") and hasattr(video, "cpu"):
        video = video.detach().cpu().numpy()
    video = np.asarray(video)
    if video.dtype == np.uint8:
        return video
    if np.issubdtype(video.dtype, np.floating):
        return np.clip(np.rint(video * 255.0), 0, 255).astype(np.uint8)
    raise MetricInputError("video", "dtype", "uint8, or float in [0, 1]", str(video.dtype))


def _load_frames(video, source: str) -> np.ndarray:
    if isinstance(video, (str, os.PathLike)):
        from .video import load_video

        try:
            arr = load_video(video)
        except MetricInputError:
            raise
        except (OSError, ValueError) as exc:
            raise MetricInputError(video, "video", "a readable video", f"{type(exc).__name__}: {exc}") from None
    else:
        arr = video
    arr = _to_uint8(arr)
    if arr.ndim != 4 or arr.shape[-1] != 3 or len(arr) == 0:
        raise MetricInputError(source, "video", "(T, H, W, 3) RGB frames with T >= 1", f"shape {arr.shape}")
    return arr


def _fit(frame: np.ndarray, max_side: int | None) -> np.ndarray:
    h, w = frame.shape[:2]
    if not max_side or max(h, w) <= max_side:
        return frame
    import cv2

    scale = max_side / max(h, w)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    return cv2.resize(frame, size, interpolation=cv2.INTER_AREA)


def _side_by_side(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    import cv2

    h = left.shape[0]
    if right.shape[0] != h:
        right = cv2.resize(right, (max(1, round(right.shape[1] * h / right.shape[0])), h), interpolation=cv2.INTER_AREA)
    bar = np.full((h, _SEPARATOR_PX, 3), 128, dtype=np.uint8)
    return np.concatenate([left, bar, right], axis=1)


def _encode_image(frame: np.ndarray, image_format: str, quality: int) -> str:
    import cv2

    bgr = np.ascontiguousarray(frame[..., ::-1])
    if image_format == "jpeg":
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
        mime = "image/jpeg"
    else:
        ok, buf = cv2.imencode(".png", bgr)
        mime = "image/png"
    if not ok:
        raise ValueError(f"could not encode a {frame.shape} frame as {image_format}")
    return f"data:{mime};base64,{base64.b64encode(buf.tobytes()).decode('ascii')}"


def _image_part(url: str) -> dict:
    return {"type": "image_url", "image_url": {"url": url}}


# --------------------------------------------------------------------------- #
# content hashes and the cache
# --------------------------------------------------------------------------- #
def _hash_file(h, path: Path) -> None:
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)


def _content_hash(video) -> str:
    h = hashlib.sha256()
    if isinstance(video, (str, os.PathLike)):
        p = Path(video)
        if p.is_dir():
            h.update(b"frames-folder\0")
            for f in sorted(x for x in p.iterdir() if x.is_file()):
                h.update(f.name.encode() + b"\0")
                _hash_file(h, f)
        else:
            h.update(b"file\0")
            _hash_file(h, p)
    else:
        arr = np.ascontiguousarray(_to_uint8(video))
        h.update(f"array\0{arr.dtype.str}\0{arr.shape}\0".encode())
        h.update(arr.tobytes())
    return h.hexdigest()
