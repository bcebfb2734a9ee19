"""Video files: H.264 MP4 for people, lossless FFV1 or PNG frames for training data.

All writers take ``(T, H, W, 3)`` uint8 RGB (or an iterable of ``(H, W, 3)``
frames, so long videos can stream) and write under a temporary name in the
target folder, renamed into place only when complete: a crash never leaves a
half-written video.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from fractions import Fraction
from pathlib import Path
from typing import Iterable

import numpy as np

from ._atomic import atomic_output
from .errors import OutputPathError

__all__ = ["write_video", "read_video", "video_info", "SUPPORTED_OUTPUTS"]

SUPPORTED_OUTPUTS = {".mp4": "H.264 (libx264, yuv420p)", ".mkv": "FFV1 lossless RGB", "folder/": "PNG frames"}
FRAME_PATTERN = "frame_{:06d}.png"


def _is_frame_folder(path: Path, raw: str) -> bool:
    return raw.endswith(("/", os.sep)) or path.suffix == "" or path.is_dir()


def _check_frame(frame: np.ndarray, index: int, shape: tuple | None) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(f"frames: expected (H, W, 3) uint8 RGB frames, found {frame.dtype} {frame.shape} at frame {index}")
    if shape is not None and frame.shape != shape:
        raise ValueError(f"frames: expected every frame of shape {shape}, found {frame.shape} at frame {index}")
    return frame


def _frames(frames) -> Iterable[np.ndarray]:
    if isinstance(frames, np.ndarray):
        if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
            raise ValueError(f"frames: expected (T, H, W, 3) uint8 RGB, found {frames.dtype} {frames.shape}")
        if len(frames) == 0:
            raise ValueError("frames: expected at least one frame, found T = 0")
    return frames


def _rate(fps: float) -> Fraction:
    fps = float(fps)
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps: expected a positive number, found {fps}")
    return Fraction(fps).limit_denominator(1001 * 1000)


def write_video(path, frames, fps: float, *, codec: str | None = None, crf: int = 18, progress: bool = False,
                threads: int = 0) -> Path:
    """Write frames to ``path``.

    path: ``.mp4`` → H.264 (width and height must be even: yuv420p), ``.mkv``
        → FFV1 lossless RGB, a folder (trailing ``/`` or no suffix) → PNG frames.
    frames: (T, H, W, 3) uint8 RGB, or an iterable of (H, W, 3) frames.
    fps: frames per second (fractional rates such as 29.97 are kept exactly
        enough: the time base is a fraction with denominator ≤ 1001000).
    codec: override the codec chosen from the suffix ("h264", "ffv1", "png").
    threads: encoder threads (0: the encoder's automatic choice).
    Returns the final path.
    """
    raw = str(path)
    path = Path(path)
    rate = _rate(fps)
    frames = _frames(frames)
    if codec is None:
        if _is_frame_folder(path, raw):
            codec = "png"
        elif path.suffix.lower() == ".mp4":
            codec = "h264"
        elif path.suffix.lower() == ".mkv":
            codec = "ffv1"
        else:
            raise OutputPathError(path, f"unsupported suffix {path.suffix!r}; supported: "
                                        + ", ".join(f"{k} ({v})" for k, v in SUPPORTED_OUTPUTS.items()))
    if codec == "png":
        return _write_png_folder(path, frames, progress)
    if codec not in ("h264", "ffv1"):
        raise ValueError(f"codec: expected 'h264', 'ffv1' or 'png', found {codec!r}")
    with atomic_output(path) as tmp:
        _encode(tmp, frames, rate, codec, crf, progress, threads)
    return path


def _progress(frames, enabled: bool, desc: str):
    if not enabled:
        return frames
    from tqdm import tqdm

    return tqdm(frames, desc=desc, unit="frame", total=len(frames) if hasattr(frames, "__len__") else None)


def _encode(tmp: Path, frames, rate: Fraction, codec: str, crf: int, progress: bool, threads: int = 0) -> None:
    import av

    fmt = "mp4" if codec == "h264" else "matroska"
    with av.open(str(tmp), mode="w", format=fmt, options={"movflags": "+faststart"} if codec == "h264" else {}) as out:
        stream = None
        shape = None
        for i, frame in enumerate(_progress(frames, progress, f"encoding {tmp.name}")):
            frame = _check_frame(frame, i, shape)
            if stream is None:
                shape = frame.shape
                H, W = shape[:2]
                if codec == "h264" and (W % 2 or H % 2):
                    raise ValueError(f"H.264 (yuv420p) needs an even width and height, found {W}x{H}; "
                                     f"use e.g. --size {W + W % 2}x{H + H % 2} or a lossless .mkv")
                if codec == "h264":
                    stream = out.add_stream("libx264", rate=rate)
                    stream.pix_fmt = "yuv420p"
                    stream.options = {"crf": str(int(crf)), "preset": "medium"}
                    # swscale converts RGB with BT.601, limited range; say so in the
                    # stream, or players assume BT.709 for HD sizes and shift colours.
                    cc = stream.codec_context
                    cc.colorspace = cc.color_primaries = cc.color_trc = 6  # SMPTE 170M (BT.601)
                    cc.color_range = 1  # limited ("tv")
                else:
                    stream = out.add_stream("ffv1", rate=rate)
                    stream.pix_fmt = "bgr0"
                stream.width, stream.height = W, H
                stream.codec_context.thread_count = int(threads)
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
            for packet in stream.encode(vf):
                out.mux(packet)
        if stream is None:
            raise ValueError("frames: expected at least one frame, found none")
        for packet in stream.encode():
            out.mux(packet)


def _write_png_folder(path: Path, frames, progress: bool) -> Path:
    import cv2

    parent = path.parent
    if not parent.is_dir():
        raise OutputPathError(path, f"folder {parent} does not exist")
    if path.exists() and (not path.is_dir() or any(path.iterdir())):
        raise OutputPathError(path, "it exists and is not an empty folder")
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=parent))
    except OSError as exc:
        raise OutputPathError(path, exc.strerror or str(exc)) from None
    try:
        shape = None
        n = 0
        for i, frame in enumerate(_progress(frames, progress, f"writing {path.name}/")):
            frame = _check_frame(frame, i, shape)
            shape = frame.shape
            if not cv2.imwrite(str(tmp / FRAME_PATTERN.format(i)), np.ascontiguousarray(frame[..., ::-1])):
                raise OSError(f"{path}: could not encode frame {i}")
            n += 1
        if n == 0:
            raise ValueError("frames: expected at least one frame, found none")
        os.chmod(tmp, 0o755)
        if path.exists():
            path.rmdir()
        os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return path


def read_video(path, *, max_frames: int | None = None) -> np.ndarray:
    """(T, H, W, 3) uint8 RGB frames of a video file or a folder of PNG frames."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such video file or frame folder")
    if path.is_dir():
        import cv2

        files = sorted(path.glob("*.png"))[:max_frames]
        if not files:
            raise FileNotFoundError(f"{path}: folder holds no .png frames")
        frames = []
        for f in files:
            img = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if img is None:
                raise ValueError(f"{f}: not a readable PNG frame")
            if frames and img.shape != frames[0].shape:
                raise ValueError(f"{f}: frame size {img.shape[1]}x{img.shape[0]} differs from "
                                 f"{frames[0].shape[1]}x{frames[0].shape[0]} of {files[0].name}")
            frames.append(img[..., ::-1])
        return np.stack(frames)
    import av

    frames = []
    try:
        with av.open(str(path)) as container:
            for frame in container.decode(video=0):
                frames.append(frame.to_ndarray(format="rgb24"))
                if max_frames is not None and len(frames) >= max_frames:
                    break
    except av.error.FFmpegError as exc:
        raise ValueError(f"{path}: not a readable video ({exc})") from None
    if not frames:
        raise ValueError(f"{path}: the video has no frames")
    return np.stack(frames)


def video_info(path) -> dict:
    """``{"frames", "fps", "width", "height", "codec"}`` of a video file or PNG folder."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such video file or frame folder")
    if path.is_dir():
        files = sorted(path.glob("*.png"))
        first = read_video(path, max_frames=1)[0] if files else None
        return {"frames": len(files), "fps": None, "width": None if first is None else first.shape[1],
                "height": None if first is None else first.shape[0], "codec": "png"}
    import av

    with av.open(str(path)) as container:
        s = container.streams.video[0]
        frames = s.frames or sum(1 for _ in container.demux(s) if _.size)
        return {"frames": int(frames), "fps": float(s.average_rate) if s.average_rate else None,
                "width": s.codec_context.width, "height": s.codec_context.height, "codec": s.codec_context.name}
