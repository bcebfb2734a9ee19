"""Dataset adapter for the KUKA LBR iiwa 14: RH20T cfg7 → oscar ``Trajectory`` + ``Camera``.

Pure numpy. The caller reads the RH20T files (``np.load(path,
allow_pickle=True).item()``) and passes the dicts; the adapter returns a
trajectory in this embodiment's joint order with the gripper as a Robotiq
position (0 open .. 1 closed) and a static camera. Bad input raises
:class:`oscar_core.TrajectoryError` / :class:`oscar_core.CameraFileError`
naming the field, what was expected and what was found. Layout sources are in
the docstrings and ``README.md``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from oscar_core.camera import Camera, Intrinsics, as_rigid_transform
from oscar_core.errors import CameraFileError, TrajectoryError
from oscar_core.trajectory import Trajectory

from . import JOINT_NAMES

__all__ = ["from_rh20t", "rh20t_base_to_camera", "ROBOTIQ_2F85_STROKE_MM"]

EMBODIMENT = "kuka"
GRIPPER_NAMES = ("gripper",)
ROBOTIQ_2F85_STROKE_MM = 85.0  # RH20T: width_mm = (255 - command) / 255 * 85
ORTHO_TOL = 1e-3  # float32 rotation blocks are re-orthonormalised below this error


def _array(value: Any, source: str, field: str, what: str, error=TrajectoryError) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise error(source, field, what, f"non-numeric data of type {type(value).__name__}") from None
    if not np.isfinite(a).all():
        raise error(source, field, f"{what}, finite values", f"{int((~np.isfinite(a)).sum())} non-finite values")
    return a


def _rigid(M: np.ndarray, source: str, field: str) -> np.ndarray:
    """A 4×4 rigid transform (the first of a stack), its rotation re-orthonormalised if stored in low precision."""
    M = M.reshape(-1, 4, 4)[0] if M.size % 16 == 0 and M.size else M
    return as_rigid_transform(M, source, field, tol=ORTHO_TOL)


def _quat_wxyz(w, x, y, z) -> np.ndarray:
    n = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _get(mapping: Mapping, key: str, source: str, field: str, what: str, error=TrajectoryError):
    try:
        return mapping[key]
    except KeyError:
        raise error(source, field, f"{what} (have {sorted(mapping)})", "missing") from None


def _by_time(d: Mapping, source: str, field: str) -> dict[int, Any]:
    try:
        out = {int(k): v for k, v in d.items()}
    except (TypeError, ValueError, AttributeError):
        raise TrajectoryError(source, field, "a dict {timestamp_ms: value}", type(d).__name__) from None
    if not out:
        raise TrajectoryError(source, field, "at least one timestamped frame", "none")
    return out


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

    As ``RH20TScene.extrinsics_base_aligned`` in ``rh20t_api/scene.py``:
    ``T_cam_base = E[serial] @ inv(E[in_hand]) @ tc_mat @ inv(T_base_tcp) @ align_mat_base``
    with ``E`` from ``calib/<t>/extrinsics.npy`` (marker board → camera),
    ``tc_mat`` from ``configs.json`` (cfg7: TCP in the in-hand camera frame)
    and ``calib_tcp`` = ``[x, y, z, qw, qx, qy, qz]`` (metres, base frame), the
    TCP at calibration time (``calib/<t>/tcp.npy`` after the KUKA preprocessor,
    which converts millimetres to metres).
    """
    E = {
        k: _rigid(
            _array(v, source, f"extrinsics[{k!r}]", "a 4x4 matrix", CameraFileError), source, f"extrinsics[{k!r}]"
        )
        for k, v in extrinsics.items()
        if k in (serial, in_hand_serial)
    }
    for k in (serial, in_hand_serial):
        if k not in E:
            raise CameraFileError(
                source, f"extrinsics[{k!r}]", f"a calibrated camera (have {sorted(extrinsics)})", "missing"
            )
    tc = _rigid(_array(tcp_camera_mat, source, "tc_mat", "a 4x4 matrix", CameraFileError), source, "tc_mat")
    p = _array(calib_tcp, source, "calib_tcp", "[x, y, z, qw, qx, qy, qz]", CameraFileError).reshape(-1)
    if p.shape != (7,):
        raise CameraFileError(source, "calib_tcp", "[x, y, z, qw, qx, qy, qz] (metres)", f"shape {p.shape}")
    T_base_tcp = np.eye(4)
    T_base_tcp[:3, :3] = _quat_wxyz(*p[3:])
    T_base_tcp[:3, 3] = p[:3]
    align = (
        np.eye(4)
        if align_mat_base is None
        else _rigid(
            _array(align_mat_base, source, "align_mat_base", "a 4x4 matrix", CameraFileError), source, "align_mat_base"
        )
    )
    return _rigid(
        E[serial] @ np.linalg.inv(E[in_hand_serial]) @ tc @ np.linalg.inv(T_base_tcp) @ align,
        source,
        "base-aligned extrinsic",
    )


def from_rh20t(
    joint: Mapping,
    gripper: Mapping,
    intrinsics: Mapping,
    extrinsics_base: Mapping,
    serial: str,
    *,
    fps: float | None = None,
    image_size: tuple[int, int] = (1280, 720),
    source: str = "<rh20t cfg7>",
) -> tuple[Trajectory, Camera]:
    """An RH20T cfg7 (KUKA LBR iiwa 14 + Robotiq 2F-85) scene seen by camera ``serial``.

    Source layout (``np.load(..., allow_pickle=True).item()`` of the release
    files; meanings from ``rh20t_api/scene.py``, ``configs/configs.json``,
    ``rh20t_api/configurations.py``):

    joint: ``<scene>/transformed/joint.npy`` — {serial: {timestamp_ms: array}};
        cfg7 stores the 7 joint angles A1..A7 in radians (configs.json
        ``robot_joint_sequence`` = ``lbr_iiwa_joint_1..7``, no velocities).
    gripper: ``<scene>/transformed/gripper.npy`` — {serial: {timestamp_ms:
        {"gripper_info": [width_mm, ...], ...}}}; ``gripper_info[0]`` is the
        finger opening in millimetres, which RH20T derives from the Robotiq
        position byte c (0 = open, 255 = closed) as ``(255 - c) / 255 * 85``.
        It is turned back into the Robotiq position ``1 - width / 85``
        (0 = open, 1 = closed) and interpolated at the joint timestamps.
    intrinsics: ``calib/<t>/intrinsics.npy`` — {serial: 3x4 (or 3x3) matrix}.
    extrinsics_base: {serial: 4x4} robot base → camera (OpenCV axes) =
        ``RH20TScene.extrinsics_base_aligned``; see :func:`rh20t_base_to_camera`.
    image_size: the calibrated image size, 1280x720 (videos are released at 640x360).
    fps: default from the median timestamp step.
    """
    jd = _by_time(
        _get(joint, serial, source, f"joint[{serial!r}]", f"joint angles recorded for camera {serial}"),
        source,
        f"joint[{serial!r}]",
    )
    gd = _by_time(
        _get(gripper, serial, source, f"gripper[{serial!r}]", f"gripper states recorded for camera {serial}"),
        source,
        f"gripper[{serial!r}]",
    )
    ts = np.array(sorted(jd), dtype=np.int64)
    rows = [_array(jd[t], source, f"joint[{serial!r}][{t}]", "joint angles").reshape(-1) for t in ts.tolist()]
    if any(r.size != 7 for r in rows):
        bad = next(r.size for r in rows if r.size != 7)
        raise TrajectoryError(
            source, f"joint[{serial!r}]", f"7 values per frame: {list(JOINT_NAMES)} in radians", f"{bad} values"
        )
    q = np.stack(rows)
    if np.abs(q).max() > 2 * np.pi:
        t, j = np.unravel_index(int(np.argmax(np.abs(q))), q.shape)
        raise TrajectoryError(
            source,
            f"joint[{serial!r}]",
            "joint angles in radians (|q| <= 2 pi)",
            f"{q[t, j]:g} at frame {t}, {JOINT_NAMES[j]} (degrees?)",
        )
    gts = np.array(sorted(gd), dtype=np.int64)
    widths = []
    for t in gts.tolist():
        try:
            widths.append(float(np.asarray(gd[t]["gripper_info"], dtype=np.float64).reshape(-1)[0]))
        except (KeyError, TypeError, IndexError, ValueError):
            raise TrajectoryError(
                source, f"gripper[{serial!r}][{t}]", "a dict with 'gripper_info' ([width_mm, ...])", repr(gd[t])[:80]
            ) from None
    width_mm = np.interp(ts, gts, np.array(widths))
    slack = 0.05 * ROBOTIQ_2F85_STROKE_MM
    bad = np.flatnonzero((width_mm < -slack) | (width_mm > ROBOTIQ_2F85_STROKE_MM + slack))
    if bad.size:
        raise TrajectoryError(
            source,
            f"gripper[{serial!r}].gripper_info[0]",
            f"Robotiq 2F-85 width in millimetres in [0, {ROBOTIQ_2F85_STROKE_MM:g}]",
            f"{width_mm[bad[0]]:g} at frame {int(bad[0])} ({bad.size} frames out of range)",
        )
    position = 1.0 - np.clip(width_mm, 0.0, ROBOTIQ_2F85_STROKE_MM) / ROBOTIQ_2F85_STROKE_MM

    K = _array(
        _get(intrinsics, serial, source, f"intrinsics[{serial!r}]", "a calibrated camera", CameraFileError),
        source,
        f"intrinsics[{serial!r}]",
        "a 3x3 or 3x4 camera matrix",
        CameraFileError,
    )
    if K.shape not in ((3, 3), (3, 4)):
        raise CameraFileError(
            source, f"intrinsics[{serial!r}]", "a 3x3 or 3x4 camera matrix (pixels)", f"shape {K.shape}"
        )
    try:
        intr = Intrinsics(
            float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(image_size[0]), int(image_size[1])
        )
    except CameraFileError as e:
        raise CameraFileError(source, f"intrinsics[{serial!r}].{e.field}", e.expected, e.found) from None
    E = _rigid(
        _array(
            _get(
                extrinsics_base, serial, source, f"extrinsics_base[{serial!r}]", "a calibrated camera", CameraFileError
            ),
            source,
            f"extrinsics_base[{serial!r}]",
            "a 4x4 matrix",
            CameraFileError,
        ),
        source,
        f"extrinsics_base[{serial!r}]",
    )
    cam = Camera(intr, E, convention="opencv", direction="world_to_camera", embodiment=EMBODIMENT)

    seconds = (ts - ts[0]) / 1000.0
    if fps is None:
        if len(ts) < 2:
            raise TrajectoryError(
                source, f"joint[{serial!r}]", "two or more frames to infer the frame rate (or pass fps=)", "1 frame"
            )
        fps = 1.0 / float(np.median(np.diff(seconds)))
    traj = Trajectory(
        JOINT_NAMES, q, fps, gripper=position[:, None], gripper_names=GRIPPER_NAMES, timestamps=seconds, source=source
    )
    return traj, cam
