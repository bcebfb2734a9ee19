"""AIROA-MoMa → oscar: one episode's stored state as a ``Trajectory`` + head ``Camera``.

AIROA-MoMa (huggingface.co/datasets/airoa-org/airoa-moma) is published in the
LeRobot format, 10 frames per second. Per frame, ``observation.state`` holds
the HSR's joint positions, named in ``meta/info.json``
(``features["observation.state"]["names"]``)::

    arm_lift_joint (m), arm_flex_joint, arm_roll_joint, wrist_flex_joint,
    wrist_roll_joint, hand_motor_joint, head_pan_joint, head_tilt_joint (rad)

Some releases pad the same joints into a 32-wide vector with ``zero_*``
columns; the adapter matches columns by name, so both work. The torso lift is
not stored: the robot (and this description) moves it as half the arm lift.
The head RGB-D video (``observation.image.head``) is 640x480 and ships no
calibration, so the camera defaults to the nominal head sensor of the HSR
description (see :data:`HEAD_INTRINSICS`). Sources: ``README.md``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from oscar_core.camera import Camera, Intrinsics
from oscar_core.errors import CameraFileError, TrajectoryError
from oscar_core.trajectory import Trajectory

from . import HEAD_CAMERA_LINK, JOINTS, base_pose_from_xy_yaw

__all__ = ["from_airoa_moma", "AIROA_MOMA_FPS", "AIROA_MOMA_STATE_NAMES", "HEAD_INTRINSICS", "head_camera"]

#: frames per second of AIROA-MoMa (meta/info.json ``fps``)
AIROA_MOMA_FPS = 10.0
#: ``observation.state`` column names when a record gives none (the 8-wide layout)
AIROA_MOMA_STATE_NAMES = (
    "arm_lift_joint",
    "arm_flex_joint",
    "arm_roll_joint",
    "wrist_flex_joint",
    "wrist_roll_joint",
    "hand_motor_joint",
    "head_pan_joint",
    "head_tilt_joint",
)
#: nominal head RGB camera: the HSR description's Gazebo sensor on the head RGB-D
#: frame is 640x480 with a 1.047 rad horizontal field of view
HEAD_INTRINSICS = Intrinsics(
    fx=320.0 / math.tan(1.047 / 2.0), fy=320.0 / math.tan(1.047 / 2.0), cx=319.5, cy=239.5, width=640, height=480
)

EMBODIMENT = "hsr"
STATE_KEY = "observation.state"


def head_camera(intrinsics: Intrinsics = HEAD_INTRINSICS) -> Camera:
    """The head RGB-D camera: identity pose in ``head_rgbd_sensor_link`` (already an optical frame)."""
    return Camera(
        intrinsics,
        np.eye(4),
        convention="opencv",
        direction="camera_to_world",
        mount_link=HEAD_CAMERA_LINK,
        embodiment=EMBODIMENT,
    )


def _get(record: Any, key: str):
    try:
        return record[key]
    except (KeyError, TypeError, IndexError, ValueError):
        return None


def _array(value: Any, source: str, field: str, what: str, error=TrajectoryError) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        try:  # a parquet / pandas column whose cells are per-frame lists
            a = np.stack([np.asarray(v, dtype=np.float64) for v in value])
        except (TypeError, ValueError):
            raise error(source, field, what, f"non-numeric data of type {type(value).__name__}") from None
    if not np.isfinite(a).all():
        raise error(source, field, f"{what} with finite values", f"{int((~np.isfinite(a)).sum())} non-finite values")
    return a


def _flat_names(names: Any) -> list[str] | None:
    """LeRobot writes names as a list, a one-key dict ({"motors": [...]}) or a nested list."""
    if names is None:
        return None
    if isinstance(names, Mapping):
        if len(names) != 1:
            return None
        names = next(iter(names.values()))
    names = list(names)
    if len(names) == 1 and isinstance(names[0], (list, tuple)):
        names = list(names[0])
    return [str(n) for n in names]


def _state_names(record: Any, width: int, source: str) -> list[str]:
    names = _get(record, "names")
    if isinstance(names, Mapping) and STATE_KEY in names:
        names = names[STATE_KEY]
    info = _get(record, "info")
    if names is None and isinstance(info, Mapping):
        names = info.get("features", {}).get(STATE_KEY, {}).get("names")
    found = _flat_names(names)
    if found is None:
        if width == len(AIROA_MOMA_STATE_NAMES):
            return list(AIROA_MOMA_STATE_NAMES)
        raise TrajectoryError(
            source,
            "names",
            f"column names for {STATE_KEY!r} (record['names'] or record['info'], "
            f"the parsed meta/info.json) when it is not the 8-wide layout {list(AIROA_MOMA_STATE_NAMES)}",
            f"none, and {width} columns",
        )
    if len(found) != width:
        raise TrajectoryError(source, "names", f"{width} names, one per {STATE_KEY} column", f"{len(found)} names")
    return found


def _intrinsics_from_camera_info(info: Any, source: str) -> Intrinsics:
    """A ROS sensor_msgs/CameraInfo as a dict: width, height, K (9 numbers, row-major), D (plumb_bob)."""
    field = "camera_info"
    if not isinstance(info, Mapping):
        raise CameraFileError(
            source, field, "a mapping with width, height, K and optional D (ROS CameraInfo)", type(info).__name__
        )
    try:
        K = np.asarray(info.get("K", info.get("k")), dtype=np.float64).reshape(-1)
        width, height = int(info["width"]), int(info["height"])
    except (KeyError, TypeError, ValueError):
        raise CameraFileError(
            source, field, "width, height and K (9 numbers, row-major)", repr(dict(info))[:120]
        ) from None
    if K.shape != (9,):
        raise CameraFileError(source, f"{field}.K", "9 numbers (3x3, row-major)", f"{K.size} numbers")
    D = info.get("D", info.get("d")) or []
    D = tuple(float(v) for v in D)
    if D and not any(D):
        D = ()
    try:
        return Intrinsics(K[0], K[4], K[2], K[5], width, height, D)
    except CameraFileError as e:
        raise CameraFileError(source, f"{field}.{e.field}", e.expected, e.found) from None


def from_airoa_moma(
    record: Mapping,
    *,
    fps: float | None = None,
    camera_info: Mapping | None = None,
    source: str = "<airoa_moma record>",
) -> tuple[Trajectory, Camera]:
    """One AIROA-MoMa episode → (trajectory, head camera on ``head_rgbd_sensor_link``).

    record: mapping with
        ``"observation.state"``: (T, D) joint positions (rows may be lists, as
            read from the parquet files);
        ``"names"`` (list, or ``{"observation.state": [...]}``) or ``"info"``
            (the parsed ``meta/info.json``): column names; optional when D = 8
            (:data:`AIROA_MOMA_STATE_NAMES`);
        ``"timestamp"`` (optional): (T,) seconds;
        ``"base_pose"`` (optional): (T, 3) base x, y (m), yaw (rad) in the
            odometry frame, e.g. read from the episode's rosbag; not part of the
            published LeRobot columns. Without it the base stays at the origin,
            which does not change what the head camera sees.
    fps: default ``record["info"]["fps"]``, then the timestamps, then 10.
    camera_info: a ROS CameraInfo dict of the head RGB camera (width, height,
        K, D); default ``record["camera_info"]``, then :data:`HEAD_INTRINSICS`.
    returns: a trajectory in :data:`JOINTS` order whose gripper column
        ``hand`` is ``hand_motor_joint`` (rad), and the head camera.
    """
    raw = _get(record, STATE_KEY)
    if raw is None:
        raise TrajectoryError(source, STATE_KEY, "joint positions, shape (T, D), named by meta/info.json", "missing")
    state = _array(raw, source, STATE_KEY, "joint positions, shape (T, D)")
    if state.ndim != 2 or state.shape[0] < 1:
        raise TrajectoryError(
            source, STATE_KEY, "shape (T, D): one row of joint positions per frame", f"shape {state.shape}"
        )
    names = _state_names(record, state.shape[1], source)
    wanted = list(JOINTS) + ["hand_motor_joint"]
    missing = [n for n in wanted if n not in names]
    if missing:
        raise TrajectoryError(source, f"{STATE_KEY} names", f"the HSR joints {wanted}", f"{names}; missing {missing}")
    cols = [names.index(n) for n in wanted]
    q, hand = state[:, cols[:-1]], state[:, cols[-1:]]
    T = len(state)

    timestamps = _get(record, "timestamp")
    if timestamps is not None:
        timestamps = _array(timestamps, source, "timestamp", "timestamps (T,), seconds").reshape(-1)
        if len(timestamps) != T:
            raise TrajectoryError(source, "timestamp", f"{T} timestamps, one per state row", f"{len(timestamps)}")
    info = _get(record, "info")
    if fps is None and isinstance(info, Mapping) and info.get("fps"):
        fps = float(info["fps"])
    if fps is None and timestamps is not None and T > 1 and np.median(np.diff(timestamps)) > 0:
        fps = float(1.0 / np.median(np.diff(timestamps)))

    base_pose = None
    xyyaw = _get(record, "base_pose")
    if xyyaw is not None:
        xyyaw = _array(xyyaw, source, "base_pose", "base x, y (m), yaw (rad), shape (T, 3)")
        if xyyaw.shape != (T, 3):
            raise TrajectoryError(
                source, "base_pose", f"shape ({T}, 3): base x, y (m), yaw (rad) per frame", f"shape {xyyaw.shape}"
            )
        base_pose = base_pose_from_xy_yaw(xyyaw[:, 0], xyyaw[:, 1], xyyaw[:, 2])

    traj = Trajectory(
        JOINTS,
        q,
        fps or AIROA_MOMA_FPS,
        gripper=hand,
        gripper_names=("hand",),
        base_pose=base_pose,
        timestamps=timestamps,
        source=source,
    )
    if camera_info is None:
        camera_info = _get(record, "camera_info")
    intrinsics = HEAD_INTRINSICS if camera_info is None else _intrinsics_from_camera_info(camera_info, source)
    return traj, head_camera(intrinsics)
