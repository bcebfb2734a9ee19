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
from collections.abc import Iterable
from fractions import Fraction
from pathlib import Path

import numpy as np

from .._util.atomic import sweep_dead_temporaries, sweep_once, tmp_prefix
from .._util.log import progress_bars_enabled
from ..errors import OutputPathError
from .video_options import DEFAULT_PRESET, DEFAULT_YUV, PRESETS, YUV_PATHS

__all__ = [
    "write_video",
    "read_video",
    "video_info",
    "SUPPORTED_OUTPUTS",
    "VideoWriter",
    "check_output",
    "remove_stale_temporaries",
    "rgb_to_yuv420p",
    "output_codec",
    "PRESETS",
    "DEFAULT_PRESET",
]

SUPPORTED_OUTPUTS = {".mp4": "H.264 (libx264, yuv420p)", ".mkv": "FFV1 lossless RGB", "folder/": "PNG frames"}
FRAME_PATTERN = "frame_{:06d}.png"


FORMATS = {"mp4": "h264", "mkv": "ffv1", "png": "png"}
_TMP_MARK = ".tmp"


def _check_frame(frame: np.ndarray, index: int, shape: tuple | None) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(
            f"frames: expected (H, W, 3) uint8 RGB frames, found {frame.dtype} {frame.shape} at frame {index}"
        )
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


# ------------------------------------------------------------------ output checks


def _supported() -> str:
    return ", ".join(f"{k} ({v})" for k, v in SUPPORTED_OUTPUTS.items())


def output_codec(path, *, format: str | None = None) -> str:
    """The codec an output name asks for: "h264" (``.mp4``), "ffv1" (``.mkv``), "png"
    (a name ending in ``/``, or ``format="png"``). Raises :class:`OutputPathError`
    for a name without a suffix or an unsupported one."""
    raw = str(path)
    path = Path(path)
    if format is not None:
        if format not in FORMATS:
            raise OutputPathError(path, f"format: expected one of {', '.join(FORMATS)}, found {format!r}")
        return FORMATS[format]
    if raw.endswith(("/", os.sep)):
        return "png"
    if path.suffix.lower() in (".mp4", ".mkv"):
        return FORMATS[path.suffix.lower()[1:]]
    if path.suffix == "":
        raise OutputPathError(
            path,
            "the name has no suffix; expected "
            + _supported()
            + ' (a folder of PNG frames is asked for with a trailing /, --format png, or format="png" in Python)',
        )
    raise OutputPathError(path, f"unsupported suffix {path.suffix!r}; supported: " + _supported())


def check_output(path, *, format: str | None = None, size: tuple[int, int] | None = None) -> tuple[Path, str]:
    """Check an output target before any rendering; returns ``(path, codec)``.

    path: ``.mp4`` → "h264", ``.mkv`` → "ffv1", a name ending in ``/`` → "png"
    (a folder of PNG frames). format: "mp4", "mkv" or "png" to choose explicitly
    (``format="png"`` is how the Python API asks for a frame folder).
    size: (width, height) pixels of the frames to come; H.264 (yuv420p) needs both even.
    Raises :class:`OutputPathError` naming the path and the reason: a name
    without a suffix (no longer a silent PNG folder), an unsupported suffix, a
    folder above it that is missing or is a file, a file output where a folder
    is, a frame folder over a non-empty folder or a file, an odd H.264 size.
    """
    raw = str(path)
    path = Path(path)
    codec = output_codec(raw, format=format)
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise OutputPathError(path, f"{parent} is a file, not a folder")
            break
    if not path.parent.is_dir():
        raise OutputPathError(path, f"folder {path.parent} does not exist")
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise OutputPathError(path, f"folder {path.parent} is not writable")
    if codec == "png":
        if path.exists() and (not path.is_dir() or any(path.iterdir())):
            raise OutputPathError(path, "it exists and is not an empty folder")
    elif path.is_dir():
        raise OutputPathError(path, "it is a folder")
    if size is not None and codec == "h264" and (size[0] % 2 or size[1] % 2):
        W, H = size
        raise OutputPathError(
            path,
            f"H.264 (yuv420p) needs an even width and height, found {W}x{H}; "
            f"use e.g. --size {W + W % 2}x{H + H % 2} or a lossless .mkv",
        )
    return path, codec


# ------------------------------------------------------------- temporary outputs


def remove_stale_temporaries(path) -> list[Path]:
    """Remove the temporary files or folders a killed writer left beside ``path``.

    Writers name them ``.<name>.<pid>.<random>.tmp[<suffix>]``; one whose process
    is no longer running is stale (:func:`oscar_core._util.atomic.sweep_dead_temporaries`).
    Returns what was removed.
    """
    path = Path(path)
    return sweep_dead_temporaries(path.parent, target=path.name)


# ------------------------------------------------------------------ RGB -> YUV


# limited-range ("tv") BT.601 chroma from OpenCV's full-range YCrCb: 128 + (c - 128) * 224 / 255
_CHROMA_LUT = np.repeat(
    np.clip(np.rint(128 + (np.arange(256) - 128) * 224 / 255), 0, 255).astype(np.uint8)[:, None], 3, axis=1
).reshape(256, 1, 3)


def rgb_to_yuv420p(frame: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB (H, W even) → (H * 3 / 2, W) uint8 planar I420, BT.601 limited range.

    Luma is OpenCV's BT.601 limited-range conversion; chroma is the 2×2 mean of
    the frame (area-resized) converted to Cb/Cr. Agrees with swscale's RGB→yuv420p
    to within 1 level of luma and a few of chroma (tests/render/test_render_stream.py).
    """
    import cv2

    H, W = frame.shape[:2]
    out = np.empty((H * 3 // 2, W), np.uint8)
    out[:H] = cv2.cvtColor(frame, cv2.COLOR_RGB2YUV_I420)[:H]
    small = cv2.resize(frame, (W // 2, H // 2), interpolation=cv2.INTER_AREA)
    ycc = cv2.LUT(cv2.cvtColor(small, cv2.COLOR_RGB2YCrCb), _CHROMA_LUT)
    # the chroma planes follow the luma plane back to back in memory (I420); when H / 2 is odd a
    # plane does not fill whole rows of W, so place them through the flat view
    flat = out.reshape(-1)
    n, m = H * W, (H // 2) * (W // 2)
    flat[n : n + m] = ycc[..., 2].reshape(-1)  # Cb (U)
    flat[n + m :] = ycc[..., 1].reshape(-1)  # Cr (V)
    return out


# ------------------------------------------------------------------ the writer


class VideoWriter:
    """Incremental video writer: frames arrive in chunks, the file appears whole or not at all.

    path, format: as :func:`check_output` (checked here, before any frame).
    fps: frames per second. crf: H.264 quality (18: visually lossless for skeletons).
    preset: x264 speed preset (:data:`PRESETS`; default :data:`DEFAULT_PRESET`).
    yuv: RGB→YUV path for H.264: "opencv" (:func:`rgb_to_yuv420p`, the default)
    or "swscale" (PyAV's converter). threads: encoder threads (0: automatic).
    size: (width, height) if known, to check H.264's even sizes up front.

    Frames are written under ``.<name>.<pid>.<random>.tmp<suffix>`` beside the
    target and renamed onto it by :meth:`close`; :meth:`abort` (or an exception
    inside ``with``) removes the temporary. Opening removes stale temporaries a
    killed writer left for the same target (:func:`remove_stale_temporaries`).
    """

    def __init__(
        self,
        path,
        fps: float,
        *,
        format: str | None = None,
        crf: int = 18,
        preset: str = DEFAULT_PRESET,
        yuv: str = DEFAULT_YUV,
        threads: int = 0,
        size: tuple[int, int] | None = None,
        progress: bool = False,
        total: int | None = None,
    ):
        self.path, self.codec = check_output(path, format=format, size=size)
        self.rate = _rate(fps)
        if preset not in PRESETS:
            raise ValueError(f"preset: expected one of {', '.join(PRESETS)}, found {preset!r}")
        if yuv not in YUV_PATHS:
            raise ValueError(f"yuv: expected one of {', '.join(YUV_PATHS)}, found {yuv!r}")
        self.crf, self.preset, self.yuv, self.threads = int(crf), preset, yuv, int(threads)
        self.frames = 0
        self._shape: tuple | None = None
        self._container = self._stream = None
        self._bar = None
        self._done = False
        sweep_once(self.path.parent)  # every dead writer's temporaries in the folder, not only this target's
        try:
            if self.codec == "png":
                self.tmp = Path(tempfile.mkdtemp(prefix=tmp_prefix(self.path), suffix=_TMP_MARK, dir=self.path.parent))
            else:
                fd, tmp = tempfile.mkstemp(
                    prefix=tmp_prefix(self.path), suffix=_TMP_MARK + self.path.suffix, dir=self.path.parent
                )
                os.close(fd)
                self.tmp = Path(tmp)
        except OSError as exc:
            raise OutputPathError(self.path, exc.strerror or str(exc)) from None
        if progress and progress_bars_enabled():
            from tqdm import tqdm

            self._bar = tqdm(total=total, desc=f"writing {self.path.name}", unit="frame")

    # -- context manager
    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def write(self, frames) -> None:
        """Append (n, H, W, 3) or (H, W, 3) uint8 RGB frames."""
        if self._done:
            raise ValueError(f"{self.path}: the writer is closed")
        arr = frames if isinstance(frames, np.ndarray) and frames.ndim == 3 else None
        for frame in [arr] if arr is not None else frames:
            frame = _check_frame(frame, self.frames, self._shape)
            if self._shape is None:
                self._open(frame.shape)
            self._write_one(frame)
            self.frames += 1
            if self._bar is not None:
                self._bar.update(1)

    def _open(self, shape: tuple) -> None:
        H, W = shape[:2]
        if self.codec == "h264" and (W % 2 or H % 2):
            raise ValueError(
                f"H.264 (yuv420p) needs an even width and height, found {W}x{H}; "
                f"use e.g. --size {W + W % 2}x{H + H % 2} or a lossless .mkv"
            )
        self._shape = shape
        if self.codec == "png":
            return
        import av

        fmt = "mp4" if self.codec == "h264" else "matroska"
        opts = {"movflags": "+faststart"} if self.codec == "h264" else {}
        self._container = av.open(str(self.tmp), mode="w", format=fmt, options=opts)
        if self.codec == "h264":
            stream = self._container.add_stream("libx264", rate=self.rate)
            stream.pix_fmt = "yuv420p"
            stream.options = {"crf": str(self.crf), "preset": self.preset}
            # both RGB paths convert with BT.601, limited range; say so in the
            # stream, or players assume BT.709 for HD sizes and shift colours.
            cc = stream.codec_context
            cc.colorspace = cc.color_primaries = cc.color_trc = 6  # SMPTE 170M (BT.601)
            cc.color_range = 1  # limited ("tv")
        else:
            stream = self._container.add_stream("ffv1", rate=self.rate)
            stream.pix_fmt = "bgr0"
        stream.width, stream.height = W, H
        stream.codec_context.thread_count = self.threads
        self._stream = stream

    def _write_one(self, frame: np.ndarray) -> None:
        if self.codec == "png":
            import cv2

            name = self.tmp / FRAME_PATTERN.format(self.frames)
            if not cv2.imwrite(str(name), np.ascontiguousarray(frame[..., ::-1])):
                raise OSError(f"{self.path}: could not encode frame {self.frames}")
            return
        import av

        if self.codec == "h264" and self.yuv == "opencv":
            vf = av.VideoFrame.from_ndarray(rgb_to_yuv420p(np.ascontiguousarray(frame)), format="yuv420p")
        else:
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
        for packet in self._stream.encode(vf):
            self._container.mux(packet)

    def close(self) -> Path:
        """Finish the file and rename it onto the target; returns the target path."""
        if self._done:
            return self.path
        try:
            if self.frames == 0:
                raise ValueError("frames: expected at least one frame, found none")
            if self._container is not None:
                for packet in self._stream.encode():
                    self._container.mux(packet)
                self._container.close()
                self._container = None
            if self._bar is not None:
                self._bar.close()
            if self.codec == "png":
                os.chmod(self.tmp, 0o777 & ~_umask())
                if self.path.is_dir():
                    self.path.rmdir()  # empty (checked); a full one is never replaced
            else:
                os.chmod(self.tmp, 0o666 & ~_umask())
            os.replace(self.tmp, self.path)
        except BaseException:
            self.abort()
            raise
        self._done = True
        return self.path

    def abort(self) -> None:
        """Drop everything written so far (nothing appears at the target)."""
        self._done = True
        if self._container is not None:
            try:
                self._container.close()
            except Exception:  # noqa: BLE001 - the file is being thrown away
                pass
            self._container = None
        if self._bar is not None:
            self._bar.close()
        if self.tmp.is_dir():
            shutil.rmtree(self.tmp, ignore_errors=True)
        else:
            self.tmp.unlink(missing_ok=True)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_video(
    path,
    frames,
    fps: float,
    *,
    codec: str | None = None,
    crf: int = 18,
    progress: bool = False,
    threads: int = 0,
    preset: str = DEFAULT_PRESET,
    yuv: str = DEFAULT_YUV,
    format: str | None = None,
) -> Path:
    """Write frames to ``path``.

    path: ``.mp4`` → H.264 (width and height must be even: yuv420p), ``.mkv``
        → FFV1 lossless RGB, a name ending in ``/`` → PNG frames (a name without
        a suffix is an error; ``format="png"`` asks for a frame folder explicitly).
    frames: (T, H, W, 3) uint8 RGB, or an iterable of (H, W, 3) frames or
        (n, H, W, 3) chunks (streamed: memory does not grow with T).
    fps: frames per second (fractional rates such as 29.97 are kept exactly
        enough: the time base is a fraction with denominator ≤ 1001000).
    codec: override the codec ("h264", "ffv1", "png"); format: "mp4", "mkv", "png".
    preset, yuv, threads: see :class:`VideoWriter`.
    Returns the final path.
    """
    if codec is not None:
        inverse = {v: k for k, v in FORMATS.items()}
        if codec not in inverse:
            raise ValueError(f"codec: expected 'h264', 'ffv1' or 'png', found {codec!r}")
        format = inverse[codec]
    frames = _frames(frames)
    size = (frames.shape[2], frames.shape[1]) if isinstance(frames, np.ndarray) else None
    total = len(frames) if hasattr(frames, "__len__") else None
    writer = VideoWriter(
        path,
        fps,
        format=format,
        crf=crf,
        preset=preset,
        yuv=yuv,
        threads=threads,
        size=size,
        progress=progress,
        total=total,
    )
    with writer:
        if isinstance(frames, np.ndarray):
            writer.write(frames)
        else:
            for item in frames:
                item = np.asarray(item)
                writer.write(item if item.ndim == 4 else item[None])
    return writer.path


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
                raise ValueError(
                    f"{f}: frame size {img.shape[1]}x{img.shape[0]} differs from "
                    f"{frames[0].shape[1]}x{frames[0].shape[0]} of {files[0].name}"
                )
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
        return {
            "frames": len(files),
            "fps": None,
            "width": None if first is None else first.shape[1],
            "height": None if first is None else first.shape[0],
            "codec": "png",
        }
    import av

    with av.open(str(path)) as container:
        s = container.streams.video[0]
        frames = s.frames or sum(1 for _ in container.demux(s) if _.size)
        return {
            "frames": int(frames),
            "fps": float(s.average_rate) if s.average_rate else None,
            "width": s.codec_context.width,
            "height": s.codec_context.height,
            "codec": s.codec_context.name,
        }
