"""Cameras: calibration files, conventions, projection (the public import path of the camera modules).

The modules form one line, each importing only those before it: geometry ← extrinsics, intrinsics ← projection ←
pinhole (:class:`Camera`) ← file (the camera JSON file). Units and conventions: :mod:`oscar_core.camera.pinhole`.
"""

from .file import camera_from_dict, camera_to_dict, load_camera, save_camera
from .geometry import (
    CONVENTION_ALIASES,
    CONVENTIONS,
    DIRECTIONS,
    as_rigid_transform,
    as_rigid_transforms,
    canonical_convention,
    convention_to_opencv,
    look_at,
)
from .intrinsics import Intrinsics
from .pinhole import Camera
from .projection import Projection, project, project_points_cv

__all__ = [
    "CONVENTIONS",
    "CONVENTION_ALIASES",
    "DIRECTIONS",
    "Intrinsics",
    "Camera",
    "Projection",
    "canonical_convention",
    "as_rigid_transform",
    "as_rigid_transforms",
    "look_at",
    "convention_to_opencv",
    "project",
    "project_points_cv",
    "load_camera",
    "save_camera",
    "camera_from_dict",
    "camera_to_dict",
]
