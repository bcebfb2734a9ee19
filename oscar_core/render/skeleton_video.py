"""From a trajectory to a skeleton video: FK → projection → rasterisation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Camera, project
from ..kinematics.trajectory import Trajectory
from ..plugin.embodiment import Embodiment
from .raster import GripperMarks, SkeletonStyle

__all__ = [
    "render_skeleton_video",
    "overlay_skeleton",
    "fit_image",
    "parse_size",
    "SkeletonProjection",
    "project_skeleton",
]


def parse_size(text: str) -> tuple[int, int]:
    """``"512x288"`` → (512, 288) (width, height in pixels)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size: expected WIDTHxHEIGHT such as 512x288, found {text!r}") from None
    if w < 2 or h < 2:
        raise ValueError(f"--size: expected a size of at least 2x2 pixels, found {text!r}")
    from .._util.memory import check_fits

    # a lower bound that every command holds at least once (most hold many frames, and check again)
    check_fits((h, w, 3), 1, f"--size {text}: one RGB frame", "use a smaller --size")
    return w, h


@dataclass(frozen=True)
class SkeletonProjection:
    """Pixel-space inputs of the rasteriser for one trajectory.

    uv: (T, K, 2) pixels; usable: (T, K) bool (finite and in front of the
    camera: points off the image still anchor clipped segments);
    grippers: indicator positions and openness.
    """

    uv: np.ndarray
    usable: np.ndarray
    grippers: GripperMarks


def project_skeleton(embodiment: Embodiment, traj: Trajectory, camera: Camera, device="cpu") -> SkeletonProjection:
    """FK and projection of a checked trajectory through ``camera`` (already sized)."""
    frames = embodiment.frames(traj, device=device, mount_link=camera.mount_link)
    pts = project(frames.points, camera, mount_pose=frames.mount_pose)
    g = project(frames.gripper_points, camera, mount_pose=frames.mount_pose)
    marks = GripperMarks(uv=g.uv, visible=g.in_front, openness=frames.openness)
    return SkeletonProjection(pts.uv, pts.in_front, marks)


def render_skeleton_video(
    embodiment: Embodiment,
    traj: Trajectory,
    camera: Camera,
    size: tuple[int, int] | None = None,
    *,
    style: SkeletonStyle | None = None,
    resize_mode: str = "crop",
    device="cpu",
    camera_source: str = "<camera>",
) -> np.ndarray:
    """Render ``traj`` of ``embodiment`` seen by ``camera``.

    size: output (width, height) pixels; the camera's intrinsics are rescaled
    (``resize_mode`` "crop": centre crop to the aspect ratio, then scale;
    "stretch") from the calibration's image size. None keeps the calibration size.
    returns: (T, H, W, 3) uint8 RGB skeleton video on black.

    The frames are rendered in chunks into one array (edges crossing the near
    plane are cut there; see :mod:`oscar_core.render.skeleton_stream`); frames where the
    camera sees nothing of the robot give an ``EmptyViewWarning``. For videos
    too long to hold in memory use :func:`oscar_core.render.skeleton_stream.iter_skeleton_chunks`.
    """
    from .skeleton_stream import render_into

    return render_into(
        embodiment, traj, camera, size, style=style, resize_mode=resize_mode, device=device, camera_source=camera_source
    )


def overlay_skeleton(skeleton: np.ndarray, rgb: np.ndarray, alpha: float = 0.8) -> np.ndarray:
    """Blend a skeleton video over real frames to check a calibration.

    skeleton, rgb: (T, H, W, 3) uint8 of the same shape. Where the skeleton is
    drawn its colour covers the frame with weight ``alpha`` × its brightness
    (so anti-aliased edges blend smoothly); black pixels leave the frame as is.
    """
    if skeleton.shape != rgb.shape:
        raise ValueError(f"overlay: expected frames of shape {skeleton.shape}, found {rgb.shape}")
    s = skeleton.astype(np.float32)
    w = alpha * (s.max(axis=-1, keepdims=True) / 255.0)
    out = rgb.astype(np.float32) * (1.0 - w) + s * w
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


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
        image = image[y0 : y0 + ch, x0 : x0 + cw]
    elif mode != "stretch":
        raise ValueError(f"fit_image: mode must be 'crop' or 'stretch', found {mode!r}")
    shrinking = width < image.shape[1]
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
