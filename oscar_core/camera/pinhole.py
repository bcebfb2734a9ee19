"""A calibrated pinhole camera (:class:`Camera`): intrinsics, an extrinsic (static or per frame), its convention.

Units: lengths in metres, angles in radians, image quantities in pixels.
Pixel convention: pixel centres sit at integer coordinates, so pixel (0, 0)
covers [-0.5, 0.5) x [-0.5, 0.5) and a W x H image spans
[-0.5, W - 0.5) x [-0.5, H - 0.5).

Camera-frame conventions (``CONVENTIONS``)
------------------------------------------
``"opencv"``   (alias ``"ros_optical"``): x right, y down, z forward.
``"opengl"``   (alias ``"blender"``):     x right, y up, z backward.
``"ros_body"`` (alias ``"ros"``):         x forward, y left, z up (REP-103).

The camera package is one line of modules, each importing only those before it:
:mod:`~oscar_core.camera.geometry` (conventions, rigid transforms) ←
:mod:`~oscar_core.camera.extrinsics` (reading an extrinsic, static or per frame) and
:mod:`~oscar_core.camera.intrinsics` (:class:`~oscar_core.camera.intrinsics.Intrinsics`) ←
:mod:`~oscar_core.camera.projection` (projection with distortion) ← this module ←
:mod:`~oscar_core.camera.file` (the camera JSON file: ``load_camera``, ``save_camera``).
``oscar_core.camera`` re-exports every public name.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from oscar_core.errors import CameraFileError

from .geometry import (
    CONVENTION_NAMES,
    DIRECTIONS,
    as_float_array,
    as_rigid_transforms,
    canonical_convention,
    convention_to_opencv,
    rigid_inverse,
)
from .intrinsics import Intrinsics

__all__ = ["Camera"]


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera.

    intrinsics: Intrinsics.
    extrinsic: (4, 4) rigid transform exactly as the user gave it (stored as a
        read-only float64 copy), or (T, 4, 4), one per video frame, for a camera
        that moves (``num_frames`` is then T); its camera frame uses
        ``convention`` axes and its meaning is set by ``direction``.
    convention: camera-frame axes, a name or alias from CONVENTIONS (stored canonical).
    direction: "camera_to_world" (extrinsic = T_ref_cam, the camera pose) or
        "world_to_camera" (extrinsic = T_cam_ref).
    mount_link: None -> the reference frame is the world / robot base and the camera
        is static; a link name -> the reference frame is that link's frame and the
        link's world pose must be passed per frame (``mount_pose``).
    embodiment: optional name of the embodiment the calibration is for.
    """

    intrinsics: Intrinsics
    extrinsic: np.ndarray
    convention: str = "opencv"
    direction: str = "camera_to_world"
    mount_link: str | None = None
    embodiment: str | None = None
    _cv_from_ref: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        src = "<Camera>"
        if not isinstance(self.intrinsics, Intrinsics):
            raise CameraFileError(src, "intrinsics", "an Intrinsics instance", type(self.intrinsics).__name__)
        M = as_rigid_transforms(self.extrinsic, src, "extrinsic")
        M.setflags(write=False)
        object.__setattr__(self, "extrinsic", M)
        if not isinstance(self.convention, str) or self.convention not in CONVENTION_NAMES:
            raise CameraFileError(src, "convention", f"one of {list(CONVENTION_NAMES)}", repr(self.convention))
        object.__setattr__(self, "convention", canonical_convention(self.convention))
        if self.direction not in DIRECTIONS:
            raise CameraFileError(src, "direction", f"one of {list(DIRECTIONS)}", repr(self.direction))
        if self.mount_link is not None and (not isinstance(self.mount_link, str) or not self.mount_link):
            raise CameraFileError(src, "mount_link", "None or a non-empty link name", repr(self.mount_link))
        if self.embodiment is not None and not isinstance(self.embodiment, str):
            raise CameraFileError(src, "embodiment", "None or a string", repr(self.embodiment))

        C = convention_to_opencv(self.convention)  # T_cv_conv
        if self.direction == "camera_to_world":  # M = T_ref_conv
            cv_from_ref = C @ rigid_inverse(M)
        else:  # M = T_conv_ref
            cv_from_ref = C @ M
        cv_from_ref.setflags(write=False)
        object.__setattr__(self, "_cv_from_ref", cv_from_ref)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        return (
            self.intrinsics == other.intrinsics
            and np.array_equal(self.extrinsic, other.extrinsic)
            and (self.convention, self.direction, self.mount_link, self.embodiment)
            == (other.convention, other.direction, other.mount_link, other.embodiment)
        )

    __hash__ = None  # type: ignore[assignment]  # holds an array

    @property
    def is_static(self) -> bool:
        """True when the camera is fixed in the world frame (no mount link, one extrinsic)."""
        return self.mount_link is None and self.extrinsic.ndim == 2

    @property
    def num_frames(self) -> int | None:
        """T for a camera with one extrinsic per frame, None for one extrinsic for all frames."""
        return int(self.extrinsic.shape[0]) if self.extrinsic.ndim == 3 else None

    def check_frames(self, num_frames: int, source: str = "<camera>") -> None:
        """Raise :class:`CameraFileError` unless a per-frame camera has exactly ``num_frames`` extrinsics."""
        n = self.num_frames
        if n is not None and n != int(num_frames):
            raise CameraFileError(
                source,
                "extrinsic",
                f"{int(num_frames)} per-frame extrinsics, one per trajectory frame",
                f"{n} extrinsics",
            )

    def time_slice(self, start: int | None = None, stop: int | None = None) -> Camera:
        """The camera for frames ``start:stop`` (as ``Trajectory.time_slice``); itself when it has one extrinsic."""
        if self.num_frames is None:
            return self
        return replace(self, extrinsic=self.extrinsic[start:stop])

    def world_to_cv(self, mount_pose: Any = None) -> np.ndarray:
        """T_cv_world: maps world points (metres) into the OpenCV camera frame.

        Static camera: call without ``mount_pose``; returns (4, 4), or (T, 4, 4)
        for a camera with one extrinsic per frame.
        Mounted camera: ``mount_pose`` is the world pose T_world_link of
        ``mount_link``, (4, 4) or (T, 4, 4); returns the same shape ((T, 4, 4)
        for a per-frame camera, whose T must match).
        Passing a mount pose to a static camera, or none to a mounted one, raises.
        """
        if self.mount_link is None:
            if mount_pose is not None:
                raise ValueError(
                    "world_to_cv: this camera is static (mount_link is None) but a mount_pose was given; "
                    "set mount_link on the camera or drop mount_pose"
                )
            return self._cv_from_ref.copy()
        if mount_pose is None:
            raise ValueError(
                f"world_to_cv: the camera is mounted on link {self.mount_link!r}; "
                "pass that link's world pose as mount_pose, shape (4, 4) or (T, 4, 4)"
            )
        P = as_float_array(mount_pose)
        if P.ndim not in (2, 3) or P.shape[-2:] != (4, 4):
            raise ValueError(f"world_to_cv: mount_pose must have shape (4, 4) or (T, 4, 4), found {P.shape}")
        n = self.num_frames
        if n is not None and P.ndim == 3 and P.shape[0] != n:
            raise ValueError(
                f"world_to_cv: this camera has {n} per-frame extrinsics but mount_pose has "
                f"{P.shape[0]} frames, shape {P.shape}"
            )
        return self._cv_from_ref @ rigid_inverse(P)

    def resized(self, width: int, height: int, mode: str = "crop") -> Camera:
        """Camera with intrinsics resized for a ``width`` x ``height`` image (see Intrinsics.resized)."""
        return replace(self, intrinsics=self.intrinsics.resized(width, height, mode))
