"""Reading the first frame (fitting it to the rollout size: :func:`oscar_core.pipeline.fit_image`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputFileError

__all__ = ["read_image"]


def read_image(path) -> np.ndarray:
    """An image file (PNG, JPEG, ...) → (H, W, 3) uint8 RGB."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "image", "an existing image file (PNG, JPEG)", "no such file")
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise InputFileError(path, "image", "a readable image file (PNG, JPEG)", "a file OpenCV cannot decode")
    return np.ascontiguousarray(bgr[:, :, ::-1])
