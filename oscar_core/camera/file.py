"""The camera JSON file: :func:`load_camera`, :func:`save_camera`, and the same format as a dict
(:func:`camera_from_dict`, :func:`camera_to_dict`).

Units and conventions are in :mod:`oscar_core.camera.pinhole`'s docstring.

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

``save_camera`` (and ``camera_to_dict``) always write the ``matrix`` extrinsic form (per frame when
the camera has one extrinsic per frame).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from oscar_core._util.atomic import atomic_write_bytes
from oscar_core._util.deprecation import warn_deprecated
from oscar_core.errors import CameraFileError

from .extrinsics import read_extrinsic, read_matrix, read_number, short_repr
from .geometry import CONVENTION_NAMES, DIRECTIONS, is_int
from .intrinsics import Intrinsics
from .pinhole import Camera

__all__ = ["camera_from_dict", "camera_to_dict", "load_camera", "save_camera"]

#: the keys of a camera file (any other is an error)
TOP_KEYS = ("image_size", "intrinsics", "distortion", "extrinsic", "convention", "direction", "mount", "embodiment")


def _parse_intrinsics(d: Mapping, src: str) -> Intrinsics:
    size = d["image_size"]
    if not isinstance(size, (list, tuple)) or len(size) != 2 or not all(is_int(s) and s > 0 for s in size):
        raise CameraFileError(src, "image_size", "[width, height] as two positive integers (pixels)", short_repr(size))
    width, height = int(size[0]), int(size[1])

    intr = d["intrinsics"]
    if not isinstance(intr, Mapping):
        raise CameraFileError(src, "intrinsics", 'an object {"fx","fy","cx","cy"} or {"K"}', short_repr(intr))
    if "K" in intr:
        if set(intr) != {"K"}:
            raise CameraFileError(
                src, "intrinsics", 'either only "K" or only "fx","fy","cx","cy"', f"keys {sorted(intr)}"
            )
        K = read_matrix(src, "intrinsics.K", intr["K"], 3, 3)
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
        values = {k: read_number(src, f"intrinsics.{k}", intr[k]) for k in want}
        names = {k: f"intrinsics.{k}" for k in want}
    for k in ("fx", "fy"):
        if values[k] <= 0:
            raise CameraFileError(src, names[k], f"a positive focal length {k} (pixels)", short_repr(float(values[k])))

    dist = d.get("distortion")
    if dist is None:
        dist = []
    if not isinstance(dist, (list, tuple)):
        raise CameraFileError(src, "distortion", "a list of 4, 5, 8 or 12 numbers", short_repr(dist))
    dist = [read_number(src, f"distortion[{k}]", x) for k, x in enumerate(dist)]
    try:
        return Intrinsics(values["fx"], values["fy"], values["cx"], values["cy"], width, height, tuple(dist))
    except CameraFileError as e:  # distortion length, mostly; re-label with the file
        raise CameraFileError(src, names.get(e.field, e.field), e.expected, e.found) from None


def _parse_camera(d: Any, src: str, defaults: Any = None) -> Camera:
    if not isinstance(d, Mapping):
        raise CameraFileError(src, "<document>", "a JSON object", type(d).__name__)
    unknown = sorted(set(d) - set(TOP_KEYS))
    if unknown:
        raise CameraFileError(src, unknown[0], f"only the keys {list(TOP_KEYS)}", f"unknown keys {unknown}")
    required = {
        "image_size": "[width, height] in pixels",
        "intrinsics": '{"fx", "fy", "cx", "cy"} or {"K"}',
        "extrinsic": '{"matrix"}, {"xyz_rpy"} or {"xyz_quat_xyzw"}',
    }
    for key, what in required.items():
        if key not in d:
            raise CameraFileError(src, key, f"the required key {key!r}: {what}", "no such key")
    intrinsics = _parse_intrinsics(d, src)
    extrinsic = read_extrinsic(d["extrinsic"], src)

    convention = d.get("convention", getattr(defaults, "convention", "opencv"))
    if convention not in CONVENTION_NAMES:
        raise CameraFileError(src, "convention", f"one of {list(CONVENTION_NAMES)}", short_repr(convention))
    direction = d.get("direction", getattr(defaults, "direction", "camera_to_world"))
    if direction not in DIRECTIONS:
        raise CameraFileError(src, "direction", f"one of {list(DIRECTIONS)}", short_repr(direction))

    mount = d.get("mount")
    if mount is None or mount == "static":
        mount_link = None
    elif isinstance(mount, Mapping) and set(mount) == {"link"} and isinstance(mount["link"], str) and mount["link"]:
        mount_link = mount["link"]
    else:
        raise CameraFileError(src, "mount", 'null, "static" or {"link": "<link name>"}', short_repr(mount))

    embodiment = d.get("embodiment")
    if embodiment is not None and not isinstance(embodiment, str):
        raise CameraFileError(src, "embodiment", "a string or null", short_repr(embodiment))
    return Camera(intrinsics, extrinsic, convention, direction, mount_link, embodiment)


def camera_to_dict(camera: Camera) -> dict:
    """JSON-ready dict in the camera file format (extrinsic in ``matrix`` form)."""
    i = camera.intrinsics
    return {
        "image_size": [i.width, i.height],
        "intrinsics": {"fx": i.fx, "fy": i.fy, "cx": i.cx, "cy": i.cy},
        "distortion": list(i.distortion),
        "extrinsic": {"matrix": camera.extrinsic.tolist()},
        "convention": camera.convention,
        "direction": camera.direction,
        "mount": None if camera.mount_link is None else {"link": camera.mount_link},
        "embodiment": camera.embodiment,
    }


def camera_from_dict(d: Mapping, source: str = "<dict>", defaults: Any = None) -> Camera:
    """Build a Camera from a dict in the camera file format.

    ``source`` names the file (or object) in error messages. ``defaults``
    (e.g. an embodiment's ``CameraSpec``) supplies ``convention`` and
    ``direction`` when the dict omits them. Raises CameraFileError naming
    the source, the field, what was expected and found.
    """
    return _parse_camera(d, str(source), defaults)


def load_camera(path: str | os.PathLike, defaults: Any = None) -> Camera:
    """Read a camera JSON file (format in the module docstring).

    defaults: an object with ``convention`` and ``direction`` attributes (an
    embodiment's ``CameraSpec``) used when the file omits those keys; without
    it they default to ``"opencv"`` and ``"camera_to_world"``.

    Raises CameraFileError for a file that is missing, unreadable or not text
    (naming what it holds) and for bad content (invalid JSON reports line and column).
    """
    from .._util.json_file import read_json

    doc = read_json(path, CameraFileError, "camera calibration JSON (utf-8 text; docs/formats.md)")
    return _parse_camera(doc, str(Path(path)), defaults)


def save_camera(camera: Camera, path: str | os.PathLike) -> None:
    """Write ``camera`` as JSON to ``path`` atomically (temp file in the same directory, then rename).

    Raises OutputPathError if the directory does not exist or cannot be written;
    no temporary file is left behind.
    """
    text = json.dumps(camera_to_dict(camera), indent=2, allow_nan=False) + "\n"
    atomic_write_bytes(path, text.encode("utf-8"))


# --------------------------------------------------------------------------- deprecated methods (0.1.0's names)
def _deprecated_from_dict(cls, d: Mapping, source: str = "<dict>", defaults: Any = None) -> Camera:
    """Deprecated since 0.2.0 (removed in 0.3.0): :func:`camera_from_dict`."""
    warn_deprecated("Camera.from_dict", "oscar_core.camera.camera_from_dict(d)", "0.2.0", "0.3.0")
    return camera_from_dict(d, source, defaults)


def _deprecated_to_dict(self) -> dict:
    """Deprecated since 0.2.0 (removed in 0.3.0): :func:`camera_to_dict`."""
    warn_deprecated("Camera.to_dict", "oscar_core.camera.camera_to_dict(camera)", "0.2.0", "0.3.0")
    return camera_to_dict(self)


# The camera file format lives here, above the Camera class (oscar_core.camera's modules form one line), so the
# methods it had in 0.1.0 are attached here; every public path to Camera (oscar_core, oscar_core.camera) loads this.
Camera.from_dict = classmethod(_deprecated_from_dict)  # type: ignore[attr-defined]
Camera.to_dict = _deprecated_to_dict  # type: ignore[attr-defined]
