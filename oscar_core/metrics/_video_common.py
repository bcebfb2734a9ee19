"""Inputs shared by oscar's video metrics: frame checks, video files, TorchScript networks.

The rules (dtype, range, frame counts) are in :mod:`oscar_core.metrics.video`'s docstring.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from .common import MetricInputError

__all__ = ["DEFAULT_FRAMES", "load_torchscript", "load_video"]

#: Frames compared per clip: the paper's "first 49 frames" (Kinema4D protocol).
DEFAULT_FRAMES = 49


# --------------------------------------------------------------------------- #
# input checks
# --------------------------------------------------------------------------- #
def _as_array(video, source: str) -> np.ndarray:
    if hasattr(video, "detach") and hasattr(video, "cpu"):  # torch tensor
        video = video.detach().cpu().numpy()
    if not isinstance(video, np.ndarray):
        raise MetricInputError(source, "type", "a (T, H, W, 3) array or tensor", type(video).__name__)
    if video.ndim != 4 or video.shape[-1] != 3:
        raise MetricInputError(source, "shape", "(T, H, W, 3) RGB frames", f"shape {video.shape}")
    if video.dtype == np.uint8:
        return video
    if not np.issubdtype(video.dtype, np.floating):
        raise MetricInputError(source, "dtype", "uint8 in [0, 255] or float in [0, 1]", str(video.dtype))
    if video.size:
        lo, hi = float(np.min(video)), float(np.max(video))
        if not (math.isfinite(lo) and math.isfinite(hi)) or lo < 0.0 or hi > 1.0:
            raise MetricInputError(source, "values", "float frames in [0, 1]", f"range [{lo:g}, {hi:g}]")
    return video


def _frames(video, n_frames, source: str) -> np.ndarray:
    video = _as_array(video, source)
    if n_frames is not None:
        if len(video) < n_frames:
            raise MetricInputError(source, "frames", f"at least {n_frames} frames (n_frames)", f"{len(video)} frames")
        video = video[:n_frames]
    if len(video) == 0:
        raise MetricInputError(source, "frames", "at least 1 frame", "0 frames")
    return video


def _pair(pred, gt, n_frames, source: str = "") -> tuple[np.ndarray, np.ndarray]:
    p_src, g_src = (f"{source}pred", f"{source}gt")
    pred, gt = _frames(pred, n_frames, p_src), _frames(gt, n_frames, g_src)
    if pred.shape[1:3] != gt.shape[1:3]:
        raise MetricInputError(
            p_src,
            "frame size",
            f"{gt.shape[2]}x{gt.shape[1]} (W x H, as {g_src}); resize first",
            f"{pred.shape[2]}x{pred.shape[1]}",
        )
    if n_frames is None and len(pred) != len(gt):
        raise MetricInputError(
            p_src, "frames", f"{len(gt)} frames (as {g_src}) when n_frames=None", f"{len(pred)} frames"
        )
    return pred, gt


def _unit(x: np.ndarray, dtype=np.float64) -> np.ndarray:
    """Frames in [0, 1] as ``dtype``."""
    if x.dtype == np.uint8:
        return x.astype(dtype) / 255.0
    return x.astype(dtype, copy=False)


def _torch():
    import torch

    return torch


def _to_tensor_nchw(frames: np.ndarray, device):
    """(B, H, W, 3) frames → float32 tensor (B, 3, H, W) in [-1, 1]."""
    torch = _torch()
    t = torch.from_numpy(np.ascontiguousarray(_unit(frames, np.float32))).to(device)
    return t.permute(0, 3, 1, 2) * 2.0 - 1.0


# --------------------------------------------------------------------------- #
# networks passed by the caller
# --------------------------------------------------------------------------- #
def load_torchscript(path, *, device="cpu", sha256: str | None = None, **call_kwargs) -> Callable:
    """Load a TorchScript module with ``torch.jit.load`` and return ``f(x) = module(x, **call_kwargs)``.

    Used for the feature extractors (e.g. ``i3d_torchscript.pt`` with
    ``rescale=True, resize=True, return_features=True``), an LPIPS network
    saved as TorchScript, or a VAE encoder. The file must exist locally;
    nothing is downloaded. ``sha256``: the file's bytes are read once, hashed,
    and loaded from memory only if they match (no window between the check
    and the load).
    """
    import hashlib
    import io

    torch = _torch()
    p = Path(path)
    if not p.is_file():
        raise MetricInputError(p, "file", "a TorchScript file (.pt) saved with torch.jit.save", "no such file")
    source = str(p)
    if sha256 is not None:
        data = p.read_bytes()
        digest = hashlib.sha256(data).hexdigest()
        if digest != sha256:
            raise MetricInputError(p, "sha256", sha256, digest)
        source = io.BytesIO(data)
    try:
        with warnings.catch_warnings():  # torch ≥ 2.10 flags torch.jit as deprecated; it is the format asked for
            warnings.simplefilter("ignore", DeprecationWarning)
            module = torch.jit.load(source, map_location=device)
    except Exception as exc:  # torch raises RuntimeError/ValueError with varying text
        raise MetricInputError(
            p,
            "contents",
            "a TorchScript archive (torch.jit.save)",
            f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}",
        ) from exc
    module.eval()

    def call(*args):
        return module(*args, **call_kwargs)

    call.module = module
    call.source = str(p)
    return call


def _callable(net, what: str, default_kwargs: Mapping | None = None, device="cpu") -> Callable:
    if isinstance(net, (str, os.PathLike)):
        return load_torchscript(net, device=device, **dict(default_kwargs or {}))
    if not callable(net):
        raise MetricInputError(what, "type", "a callable or a path to a TorchScript file", type(net).__name__)
    return net


def _flat(result, expected: int, what: str) -> np.ndarray:
    arr = result.detach().float().cpu().numpy() if hasattr(result, "detach") else np.asarray(result, dtype=np.float64)
    arr = arr.reshape(-1).astype(np.float64)
    if arr.size != expected:
        raise MetricInputError(what, "output", f"{expected} values (one per image pair)", f"shape {np.shape(result)}")
    return arr


def load_video(path, *, max_frames: int | None = None) -> np.ndarray:
    """Read a video file or PNG-frame folder (via ``oscar_core.media.video.read_video``, else PyAV / OpenCV),
    or a ``.npy`` array, into a (T, H, W, 3) array; ``max_frames`` stops reading early."""
    p = Path(path)
    if not p.exists():
        raise MetricInputError(p, "file", "an existing video file, frame folder or .npy array", "no such file")
    if p.suffix == ".npy":
        arr = np.load(p, mmap_mode="r")
        return _as_array(np.array(arr[:max_frames] if max_frames else arr), str(p))  # copy: writable, in RAM
    try:
        from ..media.video import read_video
    except ImportError:  # oscar_core.media.video not available: PyAV / OpenCV directly
        read_video = _read_video_fallback
    try:
        video = read_video(p, max_frames=max_frames) if max_frames else read_video(p)
    except TypeError:  # a read_video without max_frames
        video = read_video(p)
    return _as_array(np.asarray(video), str(p))


def _read_video_fallback(path, max_frames: int | None = None) -> np.ndarray:
    p = Path(path)
    if p.is_dir():
        import cv2

        files = sorted(f for f in p.iterdir() if f.suffix.lower() in (".png", ".jpg", ".jpeg"))[:max_frames]
        frames = [cv2.imread(str(f), cv2.IMREAD_COLOR) for f in files]
        frames = [cv2.cvtColor(f, cv2.COLOR_BGR2RGB) for f in frames if f is not None]
    else:
        import av

        frames = []
        with av.open(str(p)) as container:
            for frame in container.decode(video=0):
                frames.append(frame.to_ndarray(format="rgb24"))
                if max_frames and len(frames) >= max_frames:
                    break
    if not frames:
        raise MetricInputError(p, "frames", "at least 1 decodable video frame", "0 frames")
    return np.stack(frames)
