"""Reading the first frame (fitting it to the rollout size: :func:`oscar_core.render.skeleton_video.fit_image`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._util.inputs import describe_content
from ..errors import InputFileError

__all__ = ["read_image", "read_first_frame"]


def read_image(path) -> np.ndarray:
    """An image file (PNG, JPEG, ...) → (H, W, 3) uint8 RGB."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "image", "an existing image file (PNG, JPEG)", describe_content(path))
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise InputFileError(path, "image", "an image file OpenCV decodes (PNG, JPEG)", describe_content(path))
    return np.ascontiguousarray(bgr[:, :, ::-1])


def read_first_frame(path, camera, camera_source) -> np.ndarray:
    """The first frame of a rollout: ``path``'s image, (H, W, 3) uint8, checked to be the calibration's size
    (``camera.intrinsics``; ``camera_source`` names the camera file in the error)."""
    first = read_image(path)
    cam_size = (camera.intrinsics.width, camera.intrinsics.height)
    if (first.shape[1], first.shape[0]) != cam_size:
        raise InputFileError(path, "image size", f"{cam_size[0]}x{cam_size[1]} (the image size of camera "
                             f"{camera_source})", f"{first.shape[1]}x{first.shape[0]}")
    return first
