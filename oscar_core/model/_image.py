"""Reading the first frame and fitting it to the rollout size like the camera is fitted."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputFileError

__all__ = ["read_image", "fit_image"]


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


def fit_image(image: np.ndarray, width: int, height: int, mode: str = "crop") -> np.ndarray:
    """Resize ``image`` (H, W, 3) to ``width`` x ``height`` as ``Intrinsics.resized`` maps the camera.

    mode "crop": centre-crop to the target aspect ratio, then scale (the crop
    box is rounded to whole pixels: at most half a source pixel away from
    the intrinsics' fractional crop); "stretch": scale each axis.
    """
    import cv2

    h, w = image.shape[:2]
    if (w, h) == (width, height):
        return image
    if mode == "crop":
        aspect = width / height
        if w / h > aspect:
            cw, ch = int(round(h * aspect)), h
        else:
            cw, ch = w, int(round(w / aspect))
        x0, y0 = (w - cw) // 2, (h - ch) // 2
        image = image[y0:y0 + ch, x0:x0 + cw]
    elif mode != "stretch":
        raise ValueError(f"fit_image: mode must be 'crop' or 'stretch', found {mode!r}")
    shrinking = width < image.shape[1]
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
