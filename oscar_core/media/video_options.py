"""Encoder choices, importable without NumPy or PyAV (the CLI's --help lists them)."""

from __future__ import annotations

__all__ = ["PRESETS", "DEFAULT_PRESET", "YUV_PATHS", "DEFAULT_YUV"]

# x264 speed presets, fastest first; README.md lists seconds, size and PSNR per preset.
PRESETS = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower", "veryslow")
DEFAULT_PRESET = "ultrafast"
# RGB -> yuv420p conversion for H.264: "opencv" (oscar_core.media.video.rgb_to_yuv420p) or "swscale" (PyAV's)
YUV_PATHS = ("opencv", "swscale")
DEFAULT_YUV = "opencv"
