"""Pinhole intrinsics with OpenCV distortion (:class:`Intrinsics`): focal lengths, principal point, image size.

Units: pixels, with pixel centres at integer coordinates (see :mod:`oscar_core.camera.pinhole`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from oscar_core.errors import CameraFileError

from .geometry import DISTORTION_LENGTHS, is_int, is_number

__all__ = ["Intrinsics"]


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics with OpenCV distortion.

    fx, fy: focal lengths, pixels (> 0). cx, cy: principal point, pixels, with
    pixel centres at integer coordinates. width, height: image size, pixels.
    distortion: OpenCV coefficients k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4]]]
    (length 0, 4, 5, 8 or 12). They act on normalised image coordinates.

    Invalid values raise CameraFileError (a ValueError) naming the field.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        src = "<Intrinsics>"
        for name in ("fx", "fy"):
            v = getattr(self, name)
            if not is_number(v) or not math.isfinite(v) or v <= 0:
                raise CameraFileError(src, name, "a positive finite number (pixels)", repr(v))
            object.__setattr__(self, name, float(v))
        for name in ("cx", "cy"):
            v = getattr(self, name)
            if not is_number(v) or not math.isfinite(v):
                raise CameraFileError(src, name, "a finite number (pixels)", repr(v))
            object.__setattr__(self, name, float(v))
        for name in ("width", "height"):
            v = getattr(self, name)
            if not is_int(v) or v <= 0:
                raise CameraFileError(src, name, "a positive integer (pixels)", repr(v))
            object.__setattr__(self, name, int(v))
        d = self.distortion
        try:
            d = tuple(d)
        except TypeError:
            raise CameraFileError(src, "distortion", "a sequence of numbers", repr(d)) from None
        if len(d) == 14:
            raise CameraFileError(
                src,
                "distortion",
                "0, 4, 5, 8 or 12 coefficients (the 14-coefficient tilted model is not supported)",
                "14 coefficients",
            )
        if len(d) not in DISTORTION_LENGTHS:
            raise CameraFileError(src, "distortion", "0, 4, 5, 8 or 12 coefficients", f"{len(d)} coefficients")
        if not all(is_number(c) and math.isfinite(c) for c in d):
            raise CameraFileError(src, "distortion", "finite numbers", repr(list(d)))
        object.__setattr__(self, "distortion", tuple(float(c) for c in d))

    def matrix(self) -> np.ndarray:
        """Camera matrix K, shape (3, 3), pixels."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def crop(self, x0: float, y0: float, w: int, h: int) -> Intrinsics:
        """Intrinsics of the sub-image of size (w, h) whose top-left pixel is (x0, y0).

        A point at pixel (u, v) in this image is at (u - x0, v - y0) in the crop.
        Distortion coefficients are unchanged.
        """
        return replace(self, cx=self.cx - x0, cy=self.cy - y0, width=w, height=h)

    def _scaled(self, sx: float, sy: float, width: int, height: int) -> Intrinsics:
        # Pixel centres at integer coordinates: scaling by s maps c -> (c + 0.5) * s - 0.5.
        return replace(
            self,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=width,
            height=height,
        )

    def resized(self, width: int, height: int, mode: str = "crop") -> Intrinsics:
        """Intrinsics for an output image of ``width`` x ``height`` pixels.

        mode "crop": centre-crop the source image to the target aspect ratio (the
        crop offset may be fractional), then scale uniformly by s.
        mode "stretch": scale x by width / self.width and y by height / self.height.
        Scaling uses pixel centres at integer coordinates: c -> (c + 0.5) * s - 0.5,
        f -> f * s. Distortion coefficients are unchanged: they act on normalised
        coordinates, which resizing does not alter.
        """
        if not is_int(width) or not is_int(height) or width <= 0 or height <= 0:
            raise ValueError(f"resized: expected positive integer width and height, found {width!r}, {height!r}")
        width, height = int(width), int(height)
        W, H = self.width, self.height
        if mode == "stretch":
            return self._scaled(width / W, height / H, width, height)
        if mode != "crop":
            raise ValueError(f"resized: mode must be 'crop' or 'stretch', found {mode!r}")
        target_aspect = width / height
        if W / H > target_aspect:  # source too wide: crop columns
            cw, ch = H * target_aspect, float(H)
        else:  # source too tall: crop rows
            cw, ch = float(W), W / target_aspect
        x0, y0 = (W - cw) / 2.0, (H - ch) / 2.0
        s = width / cw
        cropped = replace(self, cx=self.cx - x0, cy=self.cy - y0)
        return cropped._scaled(s, s, width, height)
