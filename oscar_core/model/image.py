"""Reading the first frame (fitting it to the rollout size: :func:`oscar_core.render.skeleton_video.fit_image`).

A first frame is an image file (PNG, JPEG, ...) or a video file (MP4, MKV,
MOV, WebM, AVI: its frame 0), so a recorded episode can be rolled out from
its own video.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._util.inputs import describe_content
from ..errors import InputFileError

__all__ = ["VIDEO_SUFFIXES", "read_image", "read_first_frame"]

#: File suffixes read as videos (frame 0); every other file is read as an image.
VIDEO_SUFFIXES = (".mp4", ".mkv", ".mov", ".webm", ".avi", ".m4v")
_EXPECTED = "image (PNG, JPEG) or video (MP4, MKV, MOV, WebM, AVI: its frame 0)"


def read_image(path) -> np.ndarray:
    """An image file (PNG, JPEG, ...) or a video file's frame 0 (:data:`VIDEO_SUFFIXES`) → (H, W, 3) uint8 RGB."""
    import cv2

    path = Path(path)
    if path.is_dir():
        raise InputFileError(path, "image", f"a file: an {_EXPECTED}", "a folder")
    if not path.is_file():
        raise InputFileError(path, "image", f"an existing {_EXPECTED}", describe_content(path))
    if path.suffix.lower() in VIDEO_SUFFIXES:
        return _video_frame0(path)
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise InputFileError(path, "image", f"a readable {_EXPECTED}", describe_content(path))
    return np.ascontiguousarray(bgr[:, :, ::-1])


def _video_frame0(path: Path) -> np.ndarray:
    """Frame 0 of the video file ``path``, (H, W, 3) uint8 RGB (only that frame is decoded)."""
    from ..media.video import read_video

    try:
        frames = read_video(path, max_frames=1)
    except ValueError as exc:
        found = "a video without frames" if "no frames" in str(exc) else "a file that does not decode as a video"
        raise InputFileError(path, "video frame 0", f"a readable {_EXPECTED}", found) from None
    return np.ascontiguousarray(frames[0])


def read_first_frame(path, camera, camera_source) -> np.ndarray:
    """The first frame of a rollout: ``path``'s image or video frame 0, (H, W, 3) uint8, checked to be the calibration's size
    (``camera.intrinsics``; ``camera_source`` names the camera file in the error)."""
    first = read_image(path)
    cam_size = (camera.intrinsics.width, camera.intrinsics.height)
    if (first.shape[1], first.shape[0]) != cam_size:
        raise InputFileError(
            path,
            "image size",
            f"{cam_size[0]}x{cam_size[1]} (the image size of camera {camera_source})",
            f"{first.shape[1]}x{first.shape[0]}",
        )
    return first
