"""AgiBot World → oscar: one episode's stored state as a ``Trajectory`` + head ``Camera``.

AgiBot World stores, per episode (layout and field meanings from the dataset
card's "Value shapes and ranges" table, huggingface.co/datasets/agibot-world/
AgiBotWorld-Alpha; sources for every field are in ``README.md``):

``proprio_stats/<task>/<episode>/proprio_stats.h5``
    ``state/joint/position``    (N, 14) rad, left arm ``[:, :7]``, right arm ``[:, 7:]``
    ``state/waist/position``    (N, 2)  pitch ``[:, 0]`` rad, lift ``[:, 1]`` m
    ``state/head/position``     (N, 2)  yaw ``[:, 0]``, pitch ``[:, 1]`` rad
    ``action/effector/position`` (N, 2) left, right gripper, 0 = fully open, 1 = fully closed
    ``timestamp``               (N,)    nanoseconds
``parameters/<task>/<episode>/parameters/camera/``
    ``head_intrinsic_params.json``         ``{"intrinsic": {"fx", "fy", "ppx", "ppy"[, "k1", "k2", "k3", "p1", "p2"]}}``
    ``head_extrinsic_params_aligned.json`` one ``{"extrinsic": {"rotation_matrix", "translation_vector"}}``
                                           per video frame: the head camera's pose in the robot base frame

:func:`from_agibot_world` takes those arrays and parsed JSON objects in one
mapping (flat ``"state/joint/position"`` keys, nested dicts and h5py groups
all work). By default the camera keeps one pose per frame, as stored
(``head_camera="per_frame"``); ``head_camera="head_link"`` reduces the poses
to one pose relative to the head link, so the camera follows the head joints
like any mounted camera.
:func:`load_agibot_world_episode` reads an episode from a local copy of the
dataset into such a mapping (needs ``h5py``).
"""

from __future__ import annotations

import functools
import json
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from oscar_core.camera import Camera, Intrinsics
from oscar_core.embodiment import JointLimitWarning
from oscar_core.errors import CameraFileError, TrajectoryError
from oscar_core.trajectory import Trajectory

from . import HEAD_CAMERA_LINK, JOINTS

__all__ = [
    "from_agibot_world",
    "load_agibot_world_episode",
    "head_camera_in_link",
    "MountConsistencyWarning",
    "HEAD_CAMERA_MODES",
    "AGIBOT_WORLD_FPS",
    "HEAD_IMAGE_SIZE",
    "GRIPPER_NAMES",
]

#: frames per second of AgiBot World's proprioception and videos (used when no timestamps are given)
AGIBOT_WORLD_FPS = 30.0
#: (width, height) of ``head_color.mp4`` (pass ``image_size=`` if your copy differs)
HEAD_IMAGE_SIZE = (640, 480)
GRIPPER_NAMES = ("left_gripper", "right_gripper")
#: how far the per-frame head-camera poses may scatter around their mean pose in the head link
MOUNT_TOL_M = 0.02
MOUNT_TOL_RAD = float(np.deg2rad(2.0))

EMBODIMENT = "agibot_g1"
#: ``head_camera=`` of :func:`from_agibot_world`
HEAD_CAMERA_MODES = ("per_frame", "head_link")


class MountConsistencyWarning(UserWarning):
    """The per-frame head-camera poses do not agree with a camera fixed to the head link."""


# --------------------------------------------------------------------------- reading fields


def _get(record: Any, key: str, source: str, what: str, error=TrajectoryError, required: bool = True):
    """``record[key]``, or the nested path ``record[a][b][c]`` for ``key = "a/b/c"``."""
    try:
        return record[key]
    except (KeyError, TypeError, IndexError, ValueError):
        pass
    node = record
    try:
        for part in key.split("/"):
            node = node[part]
        return node
    except (KeyError, TypeError, IndexError, ValueError):
        if not required:
            return None
        raise error(source, key, what, "missing") from None


def _numbers(value: Any, source: str, key: str, what: str, error=TrajectoryError) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)  # numpy arrays, lists, h5py datasets
    except (TypeError, ValueError):
        raise error(source, key, what, f"non-numeric data of type {type(value).__name__}") from None
    if not np.isfinite(a).all():
        raise error(source, key, f"{what} with finite values", f"{int((~np.isfinite(a)).sum())} non-finite values")
    return a


def _columns(record: Any, key: str, width: int, what: str, source: str) -> np.ndarray:
    a = _numbers(_get(record, key, source, f"{what}, shape (N, {width})"), source, key, f"{what}, shape (N, {width})")
    if a.ndim != 2 or a.shape[1] != width:
        raise TrajectoryError(source, key, f"shape (N, {width}): {what}", f"shape {a.shape}")
    return a


def _seconds(raw: Any, n: int, source: str) -> np.ndarray:
    """(N,) timestamps → seconds from the first frame.

    AgiBot World stores integer nanoseconds (about 1.7e18: subtracted as
    integers, float64 would lose 0.2 µs); values whose frame step is below
    1000 are taken as seconds already.
    """
    a = np.asarray(raw).reshape(-1)
    if a.dtype.kind in "iu":
        a = (a - a[0]).astype(np.float64)
    else:
        a = _numbers(a, source, "timestamp", "timestamps (N,), nanoseconds")
        a = a - a[0]
    if len(a) != n:
        raise TrajectoryError(source, "timestamp", f"{n} timestamps, one per state frame", f"{len(a)}")
    step = np.median(np.diff(a)) if n > 1 else 0.0
    return a * 1e-9 if step > 1e3 else a


# --------------------------------------------------------------------------- camera


def _intrinsics(record: Any, image_size, source: str) -> Intrinsics:
    key = "head_intrinsic_params"
    doc = _get(
        record,
        key,
        source,
        'the parsed head_intrinsic_params.json: {"intrinsic": {"fx", "fy", "ppx", "ppy"}}',
        error=CameraFileError,
    )
    intr = doc.get("intrinsic", doc) if isinstance(doc, Mapping) else None
    if not isinstance(intr, Mapping):
        raise CameraFileError(source, key, 'an object {"intrinsic": {"fx", "fy", "ppx", "ppy"}}', type(doc).__name__)

    def number(*names):
        for n in names:
            if n in intr:
                v = intr[n]
                if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and np.isfinite(v):
                    return float(v)
                raise CameraFileError(source, f"{key}.intrinsic.{n}", "a finite number (pixels)", repr(v))
        return None

    values = {"fx": number("fx"), "fy": number("fy"), "cx": number("ppx", "cx"), "cy": number("ppy", "cy")}
    missing = [k for k, v in values.items() if v is None]
    if missing:
        raise CameraFileError(source, f"{key}.intrinsic", 'the keys "fx", "fy", "ppx", "ppy"', f"missing {missing}")
    coeffs = [number(n) for n in ("k1", "k2", "p1", "p2", "k3")]
    distortion = () if all(c is None or c == 0.0 for c in coeffs) else tuple(c or 0.0 for c in coeffs)
    if image_size is None:
        image_size = _get(record, "image_size", source, "", required=False)
    if image_size is None and number("width") is not None and number("height") is not None:
        image_size = (number("width"), number("height"))
    width, height = HEAD_IMAGE_SIZE if image_size is None else image_size
    try:
        return Intrinsics(values["fx"], values["fy"], values["cx"], values["cy"], width, height, distortion)
    except CameraFileError as e:
        field = (
            f"{key}.intrinsic.{e.field}"
            if e.field in values
            else "image_size"
            if e.field in ("width", "height")
            else e.field
        )
        raise CameraFileError(source, field, e.expected, e.found) from None


def _camera_poses(record: Any, source: str) -> np.ndarray:
    """(E, 4, 4) camera-to-base poses from the parsed head_extrinsic_params_aligned.json."""
    key = "head_extrinsic_params_aligned"
    what = 'a list of {"extrinsic": {"rotation_matrix": 3x3, "translation_vector": 3}}, one per frame'
    doc = _get(record, key, source, what, error=CameraFileError)
    items = [doc] if isinstance(doc, Mapping) else doc
    if not isinstance(items, (list, tuple)) or not items:
        raise CameraFileError(
            source, key, what, f"{type(doc).__name__} of length {len(doc) if hasattr(doc, '__len__') else '?'}"
        )
    poses = np.tile(np.eye(4), (len(items), 1, 1))
    for i, item in enumerate(items):
        ext = item.get("extrinsic", item) if isinstance(item, Mapping) else None
        try:
            R = np.asarray(ext["rotation_matrix"], dtype=np.float64)
            t = np.asarray(ext["translation_vector"], dtype=np.float64).reshape(-1)
        except (KeyError, TypeError, ValueError):
            raise CameraFileError(source, f"{key}[{i}]", what, repr(item)[:120]) from None
        if R.shape != (3, 3) or t.shape != (3,) or not (np.isfinite(R).all() and np.isfinite(t).all()):
            raise CameraFileError(
                source,
                f"{key}[{i}]",
                "a finite 3x3 rotation_matrix and 3-vector translation_vector",
                f"shapes {R.shape} and {t.shape}",
            )
        U, _, Vt = np.linalg.svd(R)  # stored with a few digits: re-orthonormalise small errors
        Rn = U @ Vt
        if np.abs(R - Rn).max() > 1e-3 or np.linalg.det(Rn) < 0:
            raise CameraFileError(
                source,
                f"{key}[{i}].rotation_matrix",
                "a rotation (orthonormal, det +1)",
                f"max |R - nearest rotation| = {np.abs(R - Rn).max():.3g}, det {np.linalg.det(R):.3g}",
            )
        poses[i, :3, :3], poses[i, :3, 3] = Rn, t
    return poses


@functools.lru_cache(maxsize=1)
def _embodiment():
    from . import AgiBotG1

    return AgiBotG1()


def head_camera_in_link(
    traj: Trajectory, camera_to_base: np.ndarray, source: str = "<agibot_world record>"
) -> np.ndarray:
    """The head camera's pose in the head link, (4, 4), from per-frame base-frame poses.

    traj: a trajectory of this embodiment (T frames); camera_to_base: (E, 4, 4)
    camera poses in the robot base frame (OpenCV axes). Frames 0..min(T, E)-1
    are paired; each gives inv(T_base_headlink(q_t)) @ T_base_cam_t, and their
    mean (rotations projected back onto SO(3)) is returned. Warns with
    :class:`MountConsistencyWarning` when a frame strays more than 2 cm / 2°
    from the mean (the extrinsics then disagree with the head kinematics).
    """
    emb = _embodiment()
    with warnings.catch_warnings():  # joints beyond their limits are reported when the trajectory is rendered
        warnings.simplefilter("ignore", JointLimitWarning)
        traj = emb.check_trajectory(traj)
    n = min(len(traj), len(camera_to_base))
    part = traj.replace(q=traj.q[:n], gripper=traj.gripper[:n], timestamps=None, base_pose=None)
    link = emb.fk(emb.full_configuration(part), links=[HEAD_CAMERA_LINK]).numpy()[:, 0]  # (n, 4, 4)
    Rl, tl = link[:, :3, :3], link[:, :3, 3]
    Rc, tc = camera_to_base[:n, :3, :3], camera_to_base[:n, :3, 3]
    R = np.einsum("nji,njk->nik", Rl, Rc)  # Rl^T Rc
    t = np.einsum("nji,nj->ni", Rl, tc - tl)
    U, _, Vt = np.linalg.svd(R.sum(axis=0))
    Rm = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    tm = t.mean(axis=0)
    dt = np.linalg.norm(t - tm, axis=1)
    cos = (np.einsum("ij,nij->n", Rm, R) - 1.0) / 2.0
    da = np.arccos(np.clip(cos, -1.0, 1.0))
    if dt.max() > MOUNT_TOL_M or da.max() > MOUNT_TOL_RAD:
        k = int(np.argmax(dt / MOUNT_TOL_M + da / MOUNT_TOL_RAD))
        warnings.warn(
            f"{source}: the head-camera extrinsics do not follow the head link rigidly: frame {k} is "
            f"{dt[k] * 100:.1f} cm / {np.rad2deg(da[k]):.1f} deg from the mean pose (tolerance "
            f"{MOUNT_TOL_M * 100:.0f} cm / {np.rad2deg(MOUNT_TOL_RAD):.0f} deg); the mean is used. Check that the "
            "extrinsics are camera-to-base and that waist/head positions match the URDF's joint zeros",
            MountConsistencyWarning,
            stacklevel=2,
        )
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = Rm, tm
    return T


# --------------------------------------------------------------------------- the adapter


def from_agibot_world(
    record: Mapping,
    *,
    image_size: tuple[int, int] | None = None,
    fps: float | None = None,
    gripper_key: str = "action/effector/position",
    head_camera: str = "per_frame",
    source: str = "<agibot_world record>",
) -> tuple[Trajectory, Camera]:
    """One AgiBot World episode → (trajectory, head camera).

    record: mapping with the proprio_stats.h5 fields ``state/joint/position``
        (N, 14) rad, ``state/waist/position`` (N, 2) [pitch rad, lift m],
        ``state/head/position`` (N, 2) [yaw, pitch] rad, the gripper field
        (N, 2) [left, right] in 0 (open) .. 1 (closed), optional ``timestamp``
        (N,) ns; and the parsed JSON files ``head_intrinsic_params`` and
        ``head_extrinsic_params_aligned`` (see the module docstring).
    image_size: (width, height) of the head video; default ``record["image_size"]``,
        then :data:`HEAD_IMAGE_SIZE`.
    fps: default from the timestamps, else :data:`AGIBOT_WORLD_FPS`.
    gripper_key: field holding the 0 (open) .. 1 (closed) gripper signals.
    head_camera: "per_frame" (default): the camera has one extrinsic per frame,
        the stored poses in the robot base frame (``mount`` static), so it
        moves exactly as recorded; the file must hold one pose per state
        frame (N), else a :class:`CameraFileError`. "head_link": one pose
        relative to ``head_link2``, the mean over the frames both hold
        (:func:`head_camera_in_link`, which warns with
        :class:`MountConsistencyWarning` when a frame strays more than 2 cm / 2°).
    returns: a trajectory in :data:`JOINTS` order with grippers
        ``("left_gripper", "right_gripper")``, and a ``Camera`` (OpenCV axes,
        camera-to-world): (N, 4, 4) base-frame poses, or with
        ``head_camera="head_link"`` one pose in ``head_link2`` that moves with
        the waist and head joints.
    """
    if head_camera not in HEAD_CAMERA_MODES:
        raise ValueError(
            f"from_agibot_world: head_camera must be one of {list(HEAD_CAMERA_MODES)}, found {head_camera!r}"
        )
    arms = _columns(record, "state/joint/position", 14, "left arm [:, :7] then right arm [:, 7:], radians", source)
    waist = _columns(record, "state/waist/position", 2, "waist pitch [:, 0] (rad), lift [:, 1] (m)", source)
    head = _columns(record, "state/head/position", 2, "head yaw [:, 0], pitch [:, 1], radians", source)
    grip = _columns(record, gripper_key, 2, "left [:, 0], right [:, 1] gripper, 0 open .. 1 closed", source)
    if grip.max() > 1.05 or grip.min() < -0.05:
        raise TrajectoryError(
            source,
            gripper_key,
            "gripper signals in 0 (open) .. 1 (closed), as action/effector/position stores them "
            "(state/effector/position is a motor reading of about 35 .. 120, not accepted)",
            f"values in [{grip.min():g}, {grip.max():g}]",
        )
    n = len(arms)
    for key, a in (("state/waist/position", waist), ("state/head/position", head), (gripper_key, grip)):
        if len(a) != n:
            raise TrajectoryError(source, key, f"{n} frames, as state/joint/position", f"{len(a)} frames")
    q = np.concatenate([waist[:, [1, 0]], head, arms], axis=1)  # lift, pitch, yaw, pitch, left 7, right 7

    timestamps = None
    ts = _get(record, "timestamp", source, "", required=False)
    if ts is not None:
        timestamps = _seconds(ts, n, source)
        if fps is None and n > 1 and np.median(np.diff(timestamps)) > 0:
            fps = float(1.0 / np.median(np.diff(timestamps)))
    traj = Trajectory(
        JOINTS,
        q,
        fps or AGIBOT_WORLD_FPS,
        gripper=grip,
        gripper_names=GRIPPER_NAMES,
        timestamps=timestamps,
        source=source,
    )

    intrinsics = _intrinsics(record, image_size, source)
    poses = _camera_poses(record, source)
    if head_camera == "head_link":
        extrinsic = head_camera_in_link(traj, poses, source)
        camera = Camera(
            intrinsics,
            extrinsic,
            convention="opencv",
            direction="camera_to_world",
            mount_link=HEAD_CAMERA_LINK,
            embodiment=EMBODIMENT,
        )
        return traj, camera
    if len(poses) != n:
        raise CameraFileError(
            source,
            "head_extrinsic_params_aligned",
            f"{n} poses, one per state frame (or pass head_camera='head_link' to fit one head-link "
            "pose to the frames both hold)",
            f"{len(poses)} poses",
        )
    camera = Camera(intrinsics, poses, convention="opencv", direction="camera_to_world", embodiment=EMBODIMENT)
    return traj, camera


def load_agibot_world_episode(root, task_id, episode_id, gripper_key: str = "action/effector/position") -> dict:
    """Read one episode of a local AgiBot World copy into a record for :func:`from_agibot_world`.

    root: the dataset folder holding ``proprio_stats/`` and ``parameters/``.
    Needs ``h5py`` (``pip install h5py``).
    """
    try:
        import h5py
    except ImportError:
        raise ImportError("reading AgiBot World's proprio_stats.h5 needs h5py: pip install h5py") from None
    root = Path(root)
    h5 = root / "proprio_stats" / str(task_id) / str(episode_id) / "proprio_stats.h5"
    params = [
        root / "parameters" / str(task_id) / str(episode_id) / "parameters" / "camera",
        root / "parameters" / str(task_id) / str(episode_id) / "camera",
    ]
    record: dict[str, Any] = {}
    with h5py.File(h5, "r") as f:
        for key in ("state/joint/position", "state/waist/position", "state/head/position", gripper_key, "timestamp"):
            if key in f:
                record[key] = np.asarray(f[key])
    for name in ("head_intrinsic_params", "head_extrinsic_params_aligned"):
        for folder in params:
            path = folder / f"{name}.json"
            if path.is_file():
                record[name] = json.loads(path.read_text())
                break
        else:
            raise FileNotFoundError(f"{name}.json not found in {' or '.join(str(p) for p in params)}")
    return record
