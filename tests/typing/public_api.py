"""Uses the flat public API (``from oscar_core import …``) as a user's script would. .ci/run type-checks it with mypy
(settings in pyproject.toml). Each call's result is checked with ``assert_type``, which fails on a result of type
Any: a name that the lazy ``oscar_core/__init__.py`` hid from type checkers would be Any.
tests/project/test_public_api.py runs it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from typing_extensions import assert_type

from oscar_core import (
    Camera,
    Embodiment,
    OscarError,
    Trajectory,
    get_embodiment,
    load_camera,
    load_trajectory,
    look_at,
    render_skeleton_video,
    save_camera,
    write_video,
)


def render_example(out_dir: Path, frames: int = 2) -> Path:
    """Render the first ``frames`` frames of the example arm's bundled trajectory and camera at 128×96 after a
    save/load round trip of the camera; returns the written MP4."""
    robot = assert_type(get_embodiment("toyarm"), Embodiment)
    if robot.example_trajectory is None or robot.example_camera is None:
        raise OscarError("toyarm: expected a bundled example trajectory and camera, found none")
    trajectory = assert_type(load_trajectory(robot.example_trajectory), Trajectory)
    camera = assert_type(load_camera(robot.example_camera), Camera)
    cam_path = out_dir / "camera.json"
    save_camera(camera, cam_path)
    video = assert_type(render_skeleton_video(robot, trajectory, load_camera(cam_path), size=(128, 96)), np.ndarray)
    return assert_type(write_video(out_dir / "skeleton.mp4", video[:frames], fps=trajectory.fps), Path)


def camera_pose() -> np.ndarray:
    """Camera-to-world (4, 4) of a camera 1.5 m in front of the origin, looking at it."""
    return assert_type(look_at(eye=(1.5, 0.0, 0.5), target=(0.0, 0.0, 0.2)), np.ndarray)
