"""Dataset adapters for the Franka Panda: stored state → oscar ``Trajectory`` + ``Camera``.

The field lookup, unit, rotation and camera checks that the DROID, RH20T and InternData-A1 adapters share live
in :mod:`oscar_embodiments.franka._adapter_checks`.

Every adapter is a pure-numpy function. It takes the arrays a dataset stores
(already read from disk by the caller: h5py groups, ``np.load(...).item()``
dicts, pandas columns all work, since only ``[]`` lookups and ``np.asarray``
are used) and returns a trajectory in this embodiment's joint order with the
gripper signal in its documented unit (Panda finger width, metres, 0 closed ..
0.08 open) and a static camera. Bad input raises
:class:`oscar_core.TrajectoryError` / :class:`oscar_core.CameraFileError`
naming the field, what was expected and what was found.

Sources of each layout are cited in the docstrings and in ``README.md``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from oscar_core.camera import Camera
from oscar_core.errors import CameraFileError, TrajectoryError
from oscar_core.trajectory import Trajectory

from . import JOINT_NAMES
from ._adapter_checks import (  # STATIC_TOL, ORTHO_TOL: importable from here as before
    ORTHO_TOL as ORTHO_TOL,
    STATIC_TOL as STATIC_TOL,
    _array,
    _check_range,
    _column,
    _fps_from,
    _intrinsics,
    _joints,
    _lookup,
    _radians,
    _rigid,
    _rotation_quat_wxyz,
    _rotation_xyz,
    _static,
    _timestamps_ms,
)

__all__ = [
    "from_droid",
    "from_rh20t",
    "from_interndata",
    "rh20t_base_to_camera",
    "DROID_FPS",
    "DROID_EMBODIMENTS",
    "PANDA_MAX_WIDTH",
]

EMBODIMENT = "franka"
GRIPPER_NAMES = ("gripper",)
PANDA_MAX_WIDTH = 0.08  # m, Franka Hand stroke (both fingers)
DROID_FPS = 15.0  # DROID's control loop (RobotEnv.control_hz)


# --------------------------------------------------------------------------- DROID


DROID_EMBODIMENTS = ("franka_robotiq", "franka")


def from_droid(
    record: Any,
    camera: str,
    *,
    extrinsic: Any = None,
    intrinsics: Any = None,
    image_size: tuple[int, int] = (1280, 720),
    fps: float = DROID_FPS,
    embodiment: str = "franka_robotiq",
    source: str = "<droid>",
) -> tuple[Trajectory, Camera]:
    """A DROID episode → (Trajectory, Camera) for one external (static) camera.

    Source layout (raw release, ``trajectory.h5``; written by
    ``droid/trajectory_utils/trajectory_writer.py`` from the observation dict of
    ``droid/robot_env.py`` / ``droid/franka/robot.py``):

    ``observation/robot_state/joint_positions``  (T, 7) Panda joints, radians
    ``observation/robot_state/gripper_position`` (T,) Robotiq 2F-85 position,
        0 = open .. 1 = closed (``1 - width / max_width``)
    ``observation/camera_extrinsics/<serial>_left`` (T, 6) camera pose in the
        robot base frame, ``[x, y, z, roll, pitch, yaw]``, metres / radians,
        Euler angles in scipy's ``"xyz"`` (fixed-axis) convention, OpenCV
        camera axes (from ``droid/calibration/calibration_utils.py``)
    ``observation/camera_intrinsics/<serial>_left`` (T, 3, 3) camera matrix

    The RLDS release's ``observation/joint_position`` (T, 7) and
    ``observation/gripper_position`` (T, 1) are accepted too; it carries no
    calibration, so pass ``extrinsic=`` (e.g. the 6-vector from the
    ``cam2base_extrinsics.json`` annotation file) and ``intrinsics=``.

    camera: the camera key, e.g. ``"24259877_left"``.
    extrinsic / intrinsics: override the record's calibration
        (``[x, y, z, roll, pitch, yaw]`` / 3x3 or ``(fx, fy, cx, cy)``).
    image_size: (width, height) of the images the intrinsics refer to
        (the ZED 2's HD720 mode, 1280x720, in the raw release).
    embodiment: "franka_robotiq" (default: the Robotiq 2F-85 DROID mounts;
        the gripper signal is DROID's position as stored, 0 open .. 1 closed)
        or "franka" (the Franka Hand drawn instead, the gripper as a
        Panda-equivalent width ``0.08 * (1 - position)`` m; the behaviour
        before ``franka_robotiq`` existed).
    Returns the trajectory and a camera-to-world OpenCV camera for that embodiment.
    """
    if embodiment not in DROID_EMBODIMENTS:
        raise ValueError(f"from_droid: embodiment must be one of {list(DROID_EMBODIMENTS)}, found {embodiment!r}")
    q = _joints(
        _lookup(
            record,
            ("observation/robot_state/joint_positions", "observation/joint_position"),
            source,
            "joint positions (T, 7)",
        ),
        source,
        "observation/robot_state/joint_positions",
    )
    T = len(q)
    pos = _column(
        _lookup(
            record,
            ("observation/robot_state/gripper_position", "observation/gripper_position"),
            source,
            "gripper position (T,)",
        ),
        source,
        "observation/robot_state/gripper_position",
        T,
        "Robotiq gripper position, 0 (open) .. 1 (closed)",
    )
    pos = _check_range(
        pos,
        0.0,
        1.0,
        source,
        "observation/robot_state/gripper_position",
        "DROID gripper position (0 = open, 1 = closed)",
    )
    signal = pos if embodiment == "franka_robotiq" else PANDA_MAX_WIDTH * (1.0 - pos)

    ext_field = f"observation/camera_extrinsics/{camera}"
    if extrinsic is None:
        extrinsic = _lookup(
            record,
            (ext_field,),
            source,
            f"the extrinsic of camera {camera!r} (or pass extrinsic=)",
            error=CameraFileError,
        )
    e = _array(extrinsic, source, ext_field, "[x, y, z, roll, pitch, yaw] (metres, radians)", error=CameraFileError)
    if e.shape[-1:] != (6,) or e.ndim > 2:
        raise CameraFileError(
            source, ext_field, "[x, y, z, roll, pitch, yaw] per frame, shape (6,) or (T, 6)", f"shape {e.shape}"
        )
    e = _static(e, source, ext_field, "DROID's wrist camera moves with the hand; use an external camera")
    M = np.eye(4)
    M[:3, :3] = _rotation_xyz(*e[3:6])
    M[:3, 3] = e[:3]

    int_field = f"observation/camera_intrinsics/{camera}"
    if intrinsics is None:
        intrinsics = _lookup(
            record,
            (int_field,),
            source,
            f"the intrinsics of camera {camera!r} (or pass intrinsics=)",
            error=CameraFileError,
        )
    K = _array(intrinsics, source, int_field, "a camera matrix", error=CameraFileError)
    if K.ndim == 3:
        K = K[0]
    cam = Camera(
        _intrinsics(K, image_size, source, int_field),
        M,
        convention="opencv",
        direction="camera_to_world",
        embodiment=embodiment,
    )
    traj = Trajectory(
        JOINT_NAMES,
        q,
        fps,
        gripper=signal[:, None],
        gripper_names=GRIPPER_NAMES,
        timestamps=np.arange(T) / float(fps),
        source=source,
    )
    return traj, cam


# --------------------------------------------------------------------------- RH20T


def rh20t_base_to_camera(
    extrinsics: Mapping[str, Any],
    serial: str,
    in_hand_serial: str,
    tcp_camera_mat: Any,
    calib_tcp: Any,
    align_mat_base: Any = None,
    source: str = "<rh20t calib>",
) -> np.ndarray:
    """RH20T's base-aligned extrinsic of camera ``serial``: (4, 4) robot base → camera.

    Mirrors ``RH20TScene.extrinsics_base_aligned`` (``rh20t_api/scene.py``):
    ``extrinsics[k]`` (``calib/<t>/extrinsics.npy``, shape (1, 4, 4) or (4, 4))
    maps marker-board points into camera k; the in-hand camera, the
    configuration's ``tc_mat`` (``tcp_camera_mat``, TCP pose in the in-hand
    camera frame) and the TCP pose at calibration time (``calib_tcp``,
    ``[x, y, z, qw, qx, qy, qz]`` in the base frame; ``calib/<t>/tcp.npy``
    after the configuration's preprocessor) place the base in the marker
    frame, so that::

        T_cam_base = E[serial] @ inv(E[in_hand]) @ tc_mat @ inv(T_base_tcp) @ align_mat_base
    """

    def mat(key):
        try:
            m = _array(extrinsics[key], source, f"extrinsics[{key!r}]", "a 4x4 matrix", error=CameraFileError)
        except KeyError:
            raise CameraFileError(
                source, f"extrinsics[{key!r}]", f"a calibrated camera (have {sorted(extrinsics)})", "missing"
            ) from None
        return _rigid(m.reshape(-1, 4, 4)[0], source, f"extrinsics[{key!r}]")

    tc = _rigid(_array(tcp_camera_mat, source, "tc_mat", "a 4x4 matrix", error=CameraFileError), source, "tc_mat")
    p = _array(calib_tcp, source, "calib_tcp", "[x, y, z, qw, qx, qy, qz]", error=CameraFileError).reshape(-1)
    if p.shape != (7,):
        raise CameraFileError(source, "calib_tcp", "[x, y, z, qw, qx, qy, qz] (metres)", f"shape {p.shape}")
    T_base_tcp = np.eye(4)
    T_base_tcp[:3, :3] = _rotation_quat_wxyz(*p[3:])
    T_base_tcp[:3, 3] = p[:3]
    align = (
        np.eye(4)
        if align_mat_base is None
        else _rigid(
            _array(align_mat_base, source, "align_mat_base", "a 4x4 matrix", error=CameraFileError),
            source,
            "align_mat_base",
        )
    )
    return _rigid(
        mat(serial) @ np.linalg.inv(mat(in_hand_serial)) @ tc @ np.linalg.inv(T_base_tcp) @ align,
        source,
        "base-aligned extrinsic",
    )


def _rh20t_series(joint: Mapping, gripper: Mapping, serial: str, source: str):
    """Joint rows, gripper widths (mm) at the joint timestamps, timestamps (s)."""
    if serial not in joint:
        raise TrajectoryError(
            source, f"joint[{serial!r}]", f"joint angles recorded for camera {serial} (have {sorted(joint)})", "missing"
        )
    if serial not in gripper:
        raise TrajectoryError(
            source,
            f"gripper[{serial!r}]",
            f"gripper states recorded for camera {serial} (have {sorted(gripper)})",
            "missing",
        )
    ts = _timestamps_ms(joint[serial].keys(), source, f"joint[{serial!r}]")
    gts = _timestamps_ms(gripper[serial].keys(), source, f"gripper[{serial!r}]")
    jd = {int(k): v for k, v in joint[serial].items()}
    gd = {int(k): v for k, v in gripper[serial].items()}
    rows = [_array(jd[t], source, f"joint[{serial!r}][{t}]", "joint angles").reshape(-1) for t in ts.tolist()]
    if len({r.size for r in rows}) != 1:
        raise TrajectoryError(
            source,
            f"joint[{serial!r}]",
            "the same number of values in every frame",
            f"sizes {sorted({r.size for r in rows})}",
        )
    rows = np.stack(rows)
    widths = []
    for t in gts.tolist():
        entry = gd[t]
        try:
            info = entry["gripper_info"]
        except (KeyError, TypeError, IndexError):
            raise TrajectoryError(
                source, f"gripper[{serial!r}][{t}]", "a dict with 'gripper_info' ([width_mm, ...])", repr(entry)[:80]
            ) from None
        widths.append(float(np.asarray(info, dtype=np.float64).reshape(-1)[0]))
    width_mm = np.interp(ts, gts, np.array(widths))  # RH20T's own loader interpolates linearly too
    return rows, width_mm, (ts - ts[0]) / 1000.0


def from_rh20t(
    joint: Mapping,
    gripper: Mapping,
    intrinsics: Mapping,
    extrinsics_base: Mapping,
    serial: str,
    *,
    fps: float | None = None,
    image_size: tuple[int, int] = (1280, 720),
    source: str = "<rh20t cfg5>",
) -> tuple[Trajectory, Camera]:
    """An RH20T cfg5 (Franka) scene seen by camera ``serial`` → (Trajectory, Camera).

    Source layout (RH20T release, read with ``np.load(..., allow_pickle=True).item()``;
    field meanings from ``rh20t_api/scene.py``, ``configs/configs.json`` and
    ``rh20t_api/configurations.py``):

    joint:  ``<scene>/transformed/joint.npy`` — {serial: {timestamp_ms: array}};
        for cfg5 the array is 7 joint angles (radians, ``panda_joint1..7``,
        configs.json ``robot_joint_sequence``) followed by 7 velocities.
    gripper: ``<scene>/transformed/gripper.npy`` — {serial: {timestamp_ms:
        {"gripper_info": [width_mm, ...], "gripper_command": ...}}};
        ``gripper_info[0]`` is the finger width in millimetres (0 .. 80 for
        the Franka Hand). Widths are interpolated at the joint timestamps.
    intrinsics: ``calib/<t>/intrinsics.npy`` — {serial: 3x4 (or 3x3) matrix}.
    extrinsics_base: {serial: 4x4} robot base → camera (OpenCV axes), i.e.
        ``RH20TScene.extrinsics_base_aligned``; build it from the raw
        ``calib/<t>/extrinsics.npy`` with :func:`rh20t_base_to_camera`.
    image_size: (width, height) of the calibrated images; RH20T calibrated at
        1280x720 (the released colour videos are 640x360: pass
        ``camera.resized(640, 360)`` or render at that size).
    fps: frames per second; default from the median timestamp step.
    """
    rows, width_mm, ts = _rh20t_series(joint, gripper, serial, source)
    if rows.shape[1] < 7:
        raise TrajectoryError(
            source,
            f"joint[{serial!r}]",
            "at least 7 values per frame (panda_joint1..7, radians)",
            f"{rows.shape[1]} values",
        )
    _radians(rows[:, :7], source, f"joint[{serial!r}]")
    width_mm = _check_range(
        width_mm,
        0.0,
        1000 * PANDA_MAX_WIDTH,
        source,
        f"gripper[{serial!r}].gripper_info[0]",
        "Franka Hand width in millimetres",
    )
    try:
        K = intrinsics[serial]
    except KeyError:
        raise CameraFileError(
            source, f"intrinsics[{serial!r}]", f"a calibrated camera (have {sorted(intrinsics)})", "missing"
        ) from None
    try:
        E = extrinsics_base[serial]
    except KeyError:
        raise CameraFileError(
            source, f"extrinsics_base[{serial!r}]", f"a calibrated camera (have {sorted(extrinsics_base)})", "missing"
        ) from None
    E = _rigid(
        _array(E, source, f"extrinsics_base[{serial!r}]", "a 4x4 matrix", error=CameraFileError).reshape(-1, 4, 4)[0],
        source,
        f"extrinsics_base[{serial!r}]",
    )
    cam = Camera(
        _intrinsics(K, image_size, source, f"intrinsics[{serial!r}]"),
        E,
        convention="opencv",
        direction="world_to_camera",
        embodiment=EMBODIMENT,
    )
    fps = _fps_from(ts, fps, source, f"joint[{serial!r}]")
    traj = Trajectory(
        JOINT_NAMES,
        rows[:, :7],
        fps,
        gripper=(width_mm / 1000.0)[:, None],
        gripper_names=GRIPPER_NAMES,
        timestamps=ts,
        source=source,
    )
    return traj, cam


# --------------------------------------------------------------------------- InternData-A1


def from_interndata(
    frames: Mapping[str, Any],
    *,
    camera: str = "head",
    fps: float | None = None,
    image_size: tuple[int, int] = (640, 480),
    source: str = "<interndata-a1>",
) -> tuple[Trajectory, Camera]:
    """An InternData-A1 Franka episode (LeRobot v2.1 parquet columns) → (Trajectory, Camera).

    Source layout (columns written by InternData-A1's
    ``policy/lmdb2lerobotv21/lmdb2lerobot_franka_a1.py``; the robot side by
    InternDataEngine's ``workflows/simbox/core/robots/fr3.py``):

    ``states.joint.position``  (T, 7) arm joints, radians
    ``states.gripper.position`` (T, 1) finger width, metres (2 × the finger
        joint: 0 = closed .. 0.08 = open)
    ``<camera>_camera_intrinsics`` (T, 4) ``[fx, fy, cx, cy]`` in pixels of
        the stored 640x480 video (``camera`` = ``"head"``)
    ``<camera>_camera_to_robot_extrinsics`` (T, 7) ``[x, y, z, qw, qx, qy,
        qz]``: the camera pose in the robot base frame, already in OpenCV axes
        (the converter multiplies Isaac Sim's USD camera pose by diag(1, -1, -1))
    ``timestamp`` (T,) seconds (optional; used for fps when ``fps`` is None)

    Only the static head camera is supported: the hand camera moves with the
    wrist (and the converter writes its pose into the head column).
    """
    q = _joints(
        _lookup(frames, ("states.joint.position",), source, "joint positions (T, 7)"), source, "states.joint.position"
    )
    T = len(q)
    width = _column(
        _lookup(frames, ("states.gripper.position",), source, "gripper width (T, 1)"),
        source,
        "states.gripper.position",
        T,
        "Panda finger width in metres",
    )
    width = _check_range(width, 0.0, PANDA_MAX_WIDTH, source, "states.gripper.position", "Panda finger width (metres)")
    if camera != "head":
        raise CameraFileError(
            source, "camera", "'head' (the static scene camera; the hand camera moves with the wrist)", repr(camera)
        )
    ext_field, int_field = f"{camera}_camera_to_robot_extrinsics", f"{camera}_camera_intrinsics"
    e = _array(
        _lookup(frames, (ext_field,), source, "the camera pose (T, 7)", CameraFileError),
        source,
        ext_field,
        "[x, y, z, qw, qx, qy, qz]",
        error=CameraFileError,
    )
    if e.shape[-1:] != (7,) or e.ndim > 2:
        raise CameraFileError(
            source, ext_field, "[x, y, z, qw, qx, qy, qz] per frame, shape (T, 7)", f"shape {e.shape}"
        )
    e = _static(e, source, ext_field, "the scene camera of an InternData-A1 episode does not move")
    n = float(np.linalg.norm(e[3:]))
    if abs(n - 1.0) > 1e-3:
        raise CameraFileError(
            source, ext_field, "a unit quaternion (norm within 1e-3 of 1) in [qw, qx, qy, qz]", f"norm {n:.6g}"
        )
    M = np.eye(4)
    M[:3, :3] = _rotation_quat_wxyz(*e[3:])
    M[:3, 3] = e[:3]
    K = _array(
        _lookup(frames, (int_field,), source, "the intrinsics (T, 4)", CameraFileError),
        source,
        int_field,
        "[fx, fy, cx, cy]",
        error=CameraFileError,
    )
    cam = Camera(
        _intrinsics(K[0] if K.ndim == 2 else K, image_size, source, int_field),
        M,
        convention="opencv",
        direction="camera_to_world",
        embodiment=EMBODIMENT,
    )
    timestamps = None
    try:
        timestamps = _column(_lookup(frames, ("timestamp",), source, "timestamps"), source, "timestamp", T, "seconds")
    except TrajectoryError as exc:
        if exc.found != "missing":
            raise
    if fps is None:
        if timestamps is None:
            raise TrajectoryError(source, "timestamp", "a timestamp column, or fps= (meta/info.json 'fps')", "missing")
        fps = _fps_from(timestamps, None, source, "timestamp")
    traj = Trajectory(
        JOINT_NAMES, q, fps, gripper=width[:, None], gripper_names=GRIPPER_NAMES, timestamps=timestamps, source=source
    )
    return traj, cam
