"""A condition video blended over the real frames it belongs to: the check of a calibration by eye."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import OscarError

__all__ = ["write_overlay"]


def write_overlay(
    embodiment,
    traj,
    camera,
    rgb_video,
    out,
    *,
    condition: str = "skeleton",
    style=None,
    size: tuple[int, int] | None = None,
    resize_mode: str = "crop",
    alpha: float = 0.8,
    fps: float | None = None,
    format: str | None = None,
    preset: str | None = None,
    crf: int = 18,
    yuv: str | None = None,
    device="cpu",
    camera_source: str = "<camera>",
    strict: bool = False,
) -> tuple[Path, int, tuple[int, int], float]:
    """Render ``condition`` of ``traj`` seen by ``camera`` and blend it over the frames of ``rgb_video``
    (:func:`oscar_core.render.skeleton_video.overlay_skeleton`), chunk by chunk, into ``out``.

    size: output (width, height) pixels (None: the video's); the real frames are fitted to it exactly as
    the calibration is (``resize_mode``). fps: output frame rate (None: the trajectory's). style: how the skeleton
    is drawn (a ``condition_style`` mapping; None: the standard look). The output path and the style are checked
    before anything is rendered. Returns (path written, frames, (width, height), fps).
    """
    from ..media.video import DEFAULT_PRESET, DEFAULT_YUV, VideoWriter, check_output, read_video, video_info
    from .conditions import chunk_renderer, style_for
    from .skeleton_video import fit_image, overlay_skeleton

    style = style_for(condition, style)
    check_output(out, format=format)
    if size is None:
        info = video_info(rgb_video)
        size = (info["width"], info["height"])
    rgb = read_video(rgb_video, max_frames=len(traj))
    if len(rgb) < len(traj):
        raise OscarError(
            f"{rgb_video}: expected at least {len(traj)} frames (the trajectory's length), found {len(rgb)}"
        )
    fps = fps or traj.fps
    with VideoWriter(
        out, fps, format=format, preset=preset or DEFAULT_PRESET, crf=crf, yuv=yuv or DEFAULT_YUV, size=tuple(size)
    ) as writer:
        t = 0
        for chunk in chunk_renderer(condition)(
            embodiment,
            traj,
            camera,
            tuple(size),
            style=style,
            resize_mode=resize_mode,
            device=device,
            camera_source=camera_source,
            strict=strict,
        ):
            H, W = chunk.shape[1:3]
            real = np.stack([fit_image(f, W, H, resize_mode) for f in rgb[t : t + len(chunk)]])
            writer.write(overlay_skeleton(chunk, real, alpha=alpha))
            t += len(chunk)
    return Path(writer.path), writer.frames, (int(size[0]), int(size[1])), float(fps)
