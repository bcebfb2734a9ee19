"""Pinhole cameras with OpenCV distortion: calibration files and projection.

Units: lengths in metres, angles in radians, image quantities in pixels.
Pixel convention: pixel centres sit at integer coordinates, so pixel (0, 0)
covers [-0.5, 0.5) x [-0.5, 0.5) and a W x H image spans
[-0.5, W - 0.5) x [-0.5, H - 0.5).

Camera-frame conventions (``CONVENTIONS``)
------------------------------------------
``"opencv"``   (alias ``"ros_optical"``): x right, y down, z forward.
``"opengl"``   (alias ``"blender"``):     x right, y up, z backward.
``"ros_body"`` (alias ``"ros"``):         x forward, y left, z up (REP-103).

Camera JSON file
----------------
A camera file is one JSON object::

    {
      "image_size": [1280, 720],
      "intrinsics": {"fx": 600.0, "fy": 600.0, "cx": 640.0, "cy": 360.0},
      "distortion": [-0.05, 0.01, 0.0, 0.0, 0.0],
      "extrinsic": {"xyz_rpy": [0.5, 0.0, 1.2, 0.0, 0.6, 3.14159]},
      "convention": "opencv",
      "direction": "camera_to_world",
      "mount": null,
      "embodiment": "franka"
    }

Keys (any other top-level key is an error):

``image_size`` (required)
    ``[width, height]``, positive integers, pixels.
``intrinsics`` (required)
    ``{"fx", "fy", "cx", "cy"}`` in pixels, or ``{"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]}``
    (no skew).
``distortion`` (optional, default none)
    OpenCV coefficients ``k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4]]]``:
    4, 5, 8 or 12 numbers. The 14-coefficient tilted model is not supported.
``extrinsic`` (required) -- exactly one of
    ``{"matrix": 4x4 nested list}``;
    ``{"xyz_rpy": [x, y, z, roll, pitch, yaw]}`` metres / radians with
    ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (fixed-axis XYZ, the same as
    ``scipy.spatial.transform.Rotation.from_euler("xyz", [roll, pitch, yaw])``);
    ``{"xyz_quat_xyzw": [x, y, z, qx, qy, qz, qw]}`` (the quaternion norm must be
    within 1e-3 of 1; it is then normalised).
    Per frame (a camera that moves: a head camera given per frame, egocentric
    video): the same keys holding one value per video frame, ``{"matrix":
    [4x4, 4x4, ...]}`` (T, 4, 4), ``{"xyz_rpy": [[...6], ...]}`` (T, 6) or
    ``{"xyz_quat_xyzw": [[...7], ...]}`` (T, 7). T must equal the trajectory's
    frame count. With ``mount: null`` each is the camera in the world / base
    frame at that frame; with a mount link, its offset from the link at that frame.
``convention`` (optional, default ``"opencv"``)
    Axes of the camera frame the extrinsic refers to; see above.
``direction`` (optional, default ``"camera_to_world"``)
    ``"camera_to_world"``: the extrinsic is the camera pose in the reference
    frame (T_ref_cam). ``"world_to_camera"``: it maps reference-frame points into
    the camera frame (T_cam_ref).
``mount`` (optional, default ``null``)
    ``null`` or ``"static"``: the reference frame is the robot base / world frame.
    ``{"link": "head_link"}``: the reference frame is that link's frame and the
    camera moves with it; the link's world pose must be supplied per frame.
``embodiment`` (optional)
    Name of the embodiment this calibration was made for (a string).

``save_camera`` always writes the ``matrix`` extrinsic form (per frame when
the camera has one extrinsic per frame).

The parts live in their own modules: :mod:`oscar_core.camera.geometry` (conventions,
rigid transforms), :mod:`oscar_core.camera.extrinsics` (reading the extrinsic, static or
per frame) and :mod:`oscar_core.camera.projection` (projection with distortion). This
module holds :class:`Intrinsics`, :class:`Camera` and the file reader and writer, and
re-exports every public name.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from oscar_core._util.atomic import atomic_write_bytes
from oscar_core.errors import CameraFileError

from .extrinsics import _TOP_KEYS, _matrix, _number, _parse_extrinsic, _short
from .geometry import (
    _DISTORTION_LENGTHS,
    _VALID_CONVENTION_NAMES,
    CONVENTION_ALIASES,
    CONVENTIONS,
    DIRECTIONS,
    _as_float_array,
    _is_int,
    _is_number,
    _rigid_inverse,
    as_rigid_transform,
    as_rigid_transforms,
    canonical_convention,
    convention_to_opencv,
    look_at,
)
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
]

# --------------------------------------------------------------------------- intrinsics


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
            if not _is_number(v) or not math.isfinite(v) or v <= 0:
                raise CameraFileError(src, name, "a positive finite number (pixels)", repr(v))
            object.__setattr__(self, name, float(v))
        for name in ("cx", "cy"):
            v = getattr(self, name)
            if not _is_number(v) or not math.isfinite(v):
                raise CameraFileError(src, name, "a finite number (pixels)", repr(v))
            object.__setattr__(self, name, float(v))
        for name in ("width", "height"):
            v = getattr(self, name)
            if not _is_int(v) or v <= 0:
                raise CameraFileError(src, name, "a positive integer (pixels)", repr(v))
            object.__setattr__(self, name, int(v))
        d = self.distortion
        try:
            d = tuple(d)
        except TypeError:
            raise CameraFileError(src, "distortion", "a sequence of numbers", repr(d)) from None
        if len(d) == 14:
            raise CameraFileError(
                src, "distortion",
                "0, 4, 5, 8 or 12 coefficients (the 14-coefficient tilted model is not supported)",
                "14 coefficients",
            )
        if len(d) not in _DISTORTION_LENGTHS:
            raise CameraFileError(src, "distortion", "0, 4, 5, 8 or 12 coefficients", f"{len(d)} coefficients")
        if not all(_is_number(c) and math.isfinite(c) for c in d):
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
        if not _is_int(width) or not _is_int(height) or width <= 0 or height <= 0:
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


# --------------------------------------------------------------------------- camera


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
        if not isinstance(self.convention, str) or self.convention not in _VALID_CONVENTION_NAMES:
            raise CameraFileError(src, "convention", f"one of {list(_VALID_CONVENTION_NAMES)}", repr(self.convention))
        object.__setattr__(self, "convention", canonical_convention(self.convention))
        if self.direction not in DIRECTIONS:
            raise CameraFileError(src, "direction", f"one of {list(DIRECTIONS)}", repr(self.direction))
        if self.mount_link is not None and (not isinstance(self.mount_link, str) or not self.mount_link):
            raise CameraFileError(src, "mount_link", "None or a non-empty link name", repr(self.mount_link))
        if self.embodiment is not None and not isinstance(self.embodiment, str):
            raise CameraFileError(src, "embodiment", "None or a string", repr(self.embodiment))

        C = convention_to_opencv(self.convention)  # T_cv_conv
        if self.direction == "camera_to_world":  # M = T_ref_conv
            cv_from_ref = C @ _rigid_inverse(M)
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
            raise CameraFileError(source, "extrinsic", f"{int(num_frames)} per-frame extrinsics, one per trajectory frame",
                                  f"{n} extrinsics")

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
        P = _as_float_array(mount_pose)
        if P.ndim not in (2, 3) or P.shape[-2:] != (4, 4):
            raise ValueError(f"world_to_cv: mount_pose must have shape (4, 4) or (T, 4, 4), found {P.shape}")
        n = self.num_frames
        if n is not None and P.ndim == 3 and P.shape[0] != n:
            raise ValueError(f"world_to_cv: this camera has {n} per-frame extrinsics but mount_pose has "
                             f"{P.shape[0]} frames, shape {P.shape}")
        return self._cv_from_ref @ _rigid_inverse(P)

    def resized(self, width: int, height: int, mode: str = "crop") -> Camera:
        """Camera with intrinsics resized for a ``width`` x ``height`` image (see Intrinsics.resized)."""
        return replace(self, intrinsics=self.intrinsics.resized(width, height, mode))

    def to_dict(self) -> dict:
        """JSON-ready dict in the camera file format (extrinsic in ``matrix`` form)."""
        i = self.intrinsics
        return {
            "image_size": [i.width, i.height],
            "intrinsics": {"fx": i.fx, "fy": i.fy, "cx": i.cx, "cy": i.cy},
            "distortion": list(i.distortion),
            "extrinsic": {"matrix": self.extrinsic.tolist()},
            "convention": self.convention,
            "direction": self.direction,
            "mount": None if self.mount_link is None else {"link": self.mount_link},
            "embodiment": self.embodiment,
        }

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "<dict>", defaults: Any = None) -> Camera:
        """Build a Camera from a dict in the camera file format.

        ``source`` names the file (or object) in error messages. ``defaults``
        (e.g. an embodiment's ``CameraSpec``) supplies ``convention`` and
        ``direction`` when the dict omits them. Raises CameraFileError naming
        the source, the field, what was expected and found.
        """
        return _parse_camera(d, str(source), defaults)


# --------------------------------------------------------------------------- file parsing
def _parse_intrinsics(d: Mapping, src: str) -> Intrinsics:
    size = d["image_size"]
    if not isinstance(size, (list, tuple)) or len(size) != 2 or not all(_is_int(s) and s > 0 for s in size):
        raise CameraFileError(src, "image_size", "[width, height] as two positive integers (pixels)", _short(size))
    width, height = int(size[0]), int(size[1])

    intr = d["intrinsics"]
    if not isinstance(intr, Mapping):
        raise CameraFileError(src, "intrinsics", 'an object {"fx","fy","cx","cy"} or {"K"}', _short(intr))
    if "K" in intr:
        if set(intr) != {"K"}:
            raise CameraFileError(src, "intrinsics", 'either only "K" or only "fx","fy","cx","cy"', f"keys {sorted(intr)}")
        K = _matrix(src, "intrinsics.K", intr["K"], 3, 3)
        if K[0, 1] != 0 or K[1, 0] != 0 or not np.allclose(K[2], [0, 0, 1], rtol=0, atol=1e-12):
            raise CameraFileError(src, "intrinsics.K", "[[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)", K.tolist())
        values = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
        names = dict.fromkeys(values, "intrinsics.K")
    else:
        want = ("fx", "fy", "cx", "cy")
        missing = [k for k in want if k not in intr]
        extra = sorted(set(intr) - set(want))
        if missing or extra:
            found = f"missing {missing}" if missing else f"unknown keys {extra}"
            raise CameraFileError(src, "intrinsics", 'keys "fx", "fy", "cx", "cy" (or only "K")', found)
        values = {k: _number(src, f"intrinsics.{k}", intr[k]) for k in want}
        names = {k: f"intrinsics.{k}" for k in want}
    for k in ("fx", "fy"):
        if values[k] <= 0:
            raise CameraFileError(src, names[k], f"a positive focal length {k} (pixels)", _short(float(values[k])))

    dist = d.get("distortion")
    if dist is None:
        dist = []
    if not isinstance(dist, (list, tuple)):
        raise CameraFileError(src, "distortion", "a list of 4, 5, 8 or 12 numbers", _short(dist))
    dist = [_number(src, f"distortion[{k}]", x) for k, x in enumerate(dist)]
    try:
        return Intrinsics(values["fx"], values["fy"], values["cx"], values["cy"], width, height, tuple(dist))
    except CameraFileError as e:  # distortion length, mostly; re-label with the file
        raise CameraFileError(src, names.get(e.field, e.field), e.expected, e.found) from None


def _parse_camera(d: Any, src: str, defaults: Any = None) -> Camera:
    if not isinstance(d, Mapping):
        raise CameraFileError(src, "<document>", "a JSON object", type(d).__name__)
    unknown = sorted(set(d) - set(_TOP_KEYS))
    if unknown:
        raise CameraFileError(src, unknown[0], f"only the keys {list(_TOP_KEYS)}", f"unknown keys {unknown}")
    required = {
        "image_size": "[width, height] in pixels",
        "intrinsics": '{"fx", "fy", "cx", "cy"} or {"K"}',
        "extrinsic": '{"matrix"}, {"xyz_rpy"} or {"xyz_quat_xyzw"}',
    }
    for key, what in required.items():
        if key not in d:
            raise CameraFileError(src, key, f"the required key {key!r}: {what}", "no such key")
    intrinsics = _parse_intrinsics(d, src)
    extrinsic = _parse_extrinsic(d["extrinsic"], src)

    convention = d.get("convention", getattr(defaults, "convention", "opencv"))
    if convention not in _VALID_CONVENTION_NAMES:
        raise CameraFileError(src, "convention", f"one of {list(_VALID_CONVENTION_NAMES)}", _short(convention))
    direction = d.get("direction", getattr(defaults, "direction", "camera_to_world"))
    if direction not in DIRECTIONS:
        raise CameraFileError(src, "direction", f"one of {list(DIRECTIONS)}", _short(direction))

    mount = d.get("mount")
    if mount is None or mount == "static":
        mount_link = None
    elif isinstance(mount, Mapping) and set(mount) == {"link"} and isinstance(mount["link"], str) and mount["link"]:
        mount_link = mount["link"]
    else:
        raise CameraFileError(src, "mount", 'null, "static" or {"link": "<link name>"}', _short(mount))

    embodiment = d.get("embodiment")
    if embodiment is not None and not isinstance(embodiment, str):
        raise CameraFileError(src, "embodiment", "a string or null", _short(embodiment))
    return Camera(intrinsics, extrinsic, convention, direction, mount_link, embodiment)


def load_camera(path: str | os.PathLike, defaults: Any = None) -> Camera:
    """Read a camera JSON file (format in the module docstring).

    defaults: an object with ``convention`` and ``direction`` attributes (an
    embodiment's ``CameraSpec``) used when the file omits those keys; without
    it they default to ``"opencv"`` and ``"camera_to_world"``.

    Raises CameraFileError for bad content (invalid JSON reports line and column);
    OSError (e.g. FileNotFoundError) if the file cannot be read.
    """
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise CameraFileError(path, "<document>", "valid JSON", f"{e.msg} at line {e.lineno}, column {e.colno}") from None
    return _parse_camera(d, str(path), defaults)


def save_camera(camera: Camera, path: str | os.PathLike) -> None:
    """Write ``camera`` as JSON to ``path`` atomically (temp file in the same directory, then rename).

    Raises OutputPathError if the directory does not exist or cannot be written;
    no temporary file is left behind.
    """
    text = json.dumps(camera.to_dict(), indent=2, allow_nan=False) + "\n"
    atomic_write_bytes(path, text.encode("utf-8"))
