"""Joint trajectories and their ``.npz`` file format.

File format (NumPy ``.npz``, read with ``allow_pickle=False``):

=================  ==========  ===============================================
field              shape       meaning
=================  ==========  ===============================================
``joint_names``    (J,) str    joint names; any order, matched by name
``q``              (T, J)      joint positions, radians (revolute) / metres
                               (prismatic)
``fps``            ()          frames per second
``gripper``        (T, G)      optional: raw gripper signal per gripper, in
                               the units the embodiment documents
``gripper_names``  (G,) str    optional: names of the gripper columns
``base_pose``      (T, 4, 4)   optional: world pose of the robot's root link
                               (mobile bases, floating bases), metres
``timestamps``     (T,)        optional: seconds, informational
``keypoints``      (T, P, 3)   optional: 3D points, metres, for embodiments
                               that take their skeleton points directly
                               instead of computing them from joints (human
                               hands); NaN marks a missing point
=================  ==========  ===============================================

A trajectory with ``keypoints`` may leave out ``joint_names`` and ``q`` in the
file: they default to no joints, ``q`` of shape (T, 0).
"""

from __future__ import annotations

import dataclasses
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._util.atomic import atomic_output
from .._util.inputs import describe_content
from ..errors import TrajectoryError

__all__ = ["Trajectory", "load_trajectory", "save_trajectory", "interpolate_keyframes", "TRAJECTORY_FIELDS"]

TRAJECTORY_FIELDS = ("joint_names", "q", "fps", "gripper", "gripper_names", "base_pose", "timestamps", "keypoints")


def _first_bad(a: np.ndarray) -> tuple:
    idx = np.argwhere(~np.isfinite(a))
    return tuple(int(i) for i in idx[0]), int(len(idx))


@dataclass(frozen=True, eq=False)
class Trajectory:
    """One robot trajectory.

    joint_names: (J,) names; q: (T, J) radians / metres; fps: frames per
    second; gripper: (T, G) raw signals (G may be 0); gripper_names: (G,) or
    None; base_pose: (T, 4, 4) root-link pose in the world, or None;
    source: file name used in error messages; keypoints: (T, P, 3) points in
    metres for embodiments that read their skeleton points directly (NaN =
    missing point; inf is an error), or None. Such trajectories have no
    joints: ``joint_names=()`` and ``q`` of shape (T, 0).
    """

    joint_names: tuple[str, ...]
    q: np.ndarray
    fps: float
    gripper: np.ndarray | None = None
    gripper_names: tuple[str, ...] | None = None
    base_pose: np.ndarray | None = None
    timestamps: np.ndarray | None = None
    source: str = "<trajectory>"
    keypoints: np.ndarray | None = None

    def __post_init__(self):
        src = self.source
        names = (
            tuple(str(n) for n in np.atleast_1d(np.asarray(self.joint_names)).tolist()) if len(self.joint_names) else ()
        )
        object.__setattr__(self, "joint_names", names)
        if len(set(names)) != len(names):
            raise TrajectoryError(
                src, "joint_names", "unique names", f"duplicates {sorted({n for n in names if names.count(n) > 1})}"
            )
        try:
            q = np.asarray(self.q, dtype=np.float64)
        except (TypeError, ValueError):
            raise TrajectoryError(src, "q", "numbers", f"dtype {np.asarray(self.q).dtype}") from None
        if q.ndim != 2 or q.shape[1] != len(names):
            raise TrajectoryError(src, "q", f"shape (T, {len(names)}) matching joint_names", f"shape {q.shape}")
        if q.shape[0] < 1:
            raise TrajectoryError(src, "q", "at least one frame", "T = 0")
        if not np.isfinite(q).all():
            (t, j), n = _first_bad(q)
            raise TrajectoryError(src, "q", "finite values", f"{q[t, j]} at frame {t}, joint {names[j]!r} ({n} values)")
        object.__setattr__(self, "q", q)
        T = q.shape[0]
        try:
            fps = float(np.asarray(self.fps).reshape(()))
        except (TypeError, ValueError):
            raise TrajectoryError(src, "fps", "one positive number", repr(self.fps)) from None
        if not (np.isfinite(fps) and fps > 0):
            raise TrajectoryError(src, "fps", "one positive number", repr(fps))
        object.__setattr__(self, "fps", fps)
        g = np.zeros((T, 0)) if self.gripper is None else np.asarray(self.gripper, dtype=np.float64)
        if g.ndim == 1:
            g = g[:, None]
        if g.ndim != 2 or g.shape[0] != T:
            raise TrajectoryError(src, "gripper", f"shape ({T}, G)", f"shape {g.shape}")
        if not np.isfinite(g).all():
            (t, k), n = _first_bad(g)
            raise TrajectoryError(src, "gripper", "finite values", f"{g[t, k]} at frame {t}, column {k} ({n} values)")
        object.__setattr__(self, "gripper", g)
        if self.gripper_names is not None:
            gn = tuple(str(n) for n in np.atleast_1d(np.asarray(self.gripper_names)).tolist())
            if len(gn) != g.shape[1]:
                raise TrajectoryError(
                    src, "gripper_names", f"{g.shape[1]} names (one per gripper column)", f"{len(gn)}"
                )
            object.__setattr__(self, "gripper_names", gn)
        if self.base_pose is not None:
            b = np.asarray(self.base_pose, dtype=np.float64)
            if b.shape != (T, 4, 4):
                raise TrajectoryError(src, "base_pose", f"shape ({T}, 4, 4)", f"shape {b.shape}")
            if not np.isfinite(b).all():
                (t, *_), n = _first_bad(b)
                raise TrajectoryError(src, "base_pose", "finite values", f"non-finite at frame {t}")
            R = b[:, :3, :3]
            dev = np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
            bottom = np.abs(b[:, 3] - [0, 0, 0, 1]).max(axis=1)
            if dev.max() > 1e-5 or bottom.max() > 1e-9:
                t = int(np.argmax(np.maximum(dev, bottom)))
                raise TrajectoryError(
                    src,
                    "base_pose",
                    "rigid transforms (orthonormal rotation, last row 0 0 0 1)",
                    f"rotation error {dev[t]:.2g} / last row {b[t, 3].tolist()} at frame {t}",
                )
            object.__setattr__(self, "base_pose", b)
        if self.timestamps is not None:
            ts = np.asarray(self.timestamps, dtype=np.float64)
            if ts.shape != (T,):
                raise TrajectoryError(src, "timestamps", f"shape ({T},)", f"shape {ts.shape}")
            object.__setattr__(self, "timestamps", ts)
        if self.keypoints is not None:
            try:
                kp = np.asarray(self.keypoints, dtype=np.float64)
            except (TypeError, ValueError):
                raise TrajectoryError(
                    src, "keypoints", "numbers (metres)", f"dtype {np.asarray(self.keypoints).dtype}"
                ) from None
            if kp.ndim != 3 or kp.shape[0] != T or kp.shape[2] != 3 or kp.shape[1] < 1:
                raise TrajectoryError(src, "keypoints", f"shape ({T}, P, 3) with P >= 1", f"shape {kp.shape}")
            inf = np.isinf(kp)
            if inf.any():
                (t, k, _), n = tuple(int(i) for i in np.argwhere(inf)[0]), int(inf.sum())
                raise TrajectoryError(
                    src,
                    "keypoints",
                    "finite values or NaN (NaN marks a missing point)",
                    f"{kp[t, k].tolist()} at frame {t}, point {k} ({n} values)",
                )
            object.__setattr__(self, "keypoints", kp)

    @property
    def num_frames(self) -> int:
        return self.q.shape[0]

    def replace(self, **changes) -> Trajectory:
        return dataclasses.replace(self, **changes)

    def time_slice(self, start: int | None = None, stop: int | None = None) -> Trajectory:
        """Frames ``start:stop`` of every per-frame field (q, gripper, base pose, timestamps, keypoints)."""
        sl = slice(start, stop)
        per_frame = ("q", "gripper", "base_pose", "timestamps", "keypoints")
        return self.replace(**{f: getattr(self, f)[sl] for f in per_frame if getattr(self, f) is not None})

    def __len__(self) -> int:
        return self.num_frames


def interpolate_keyframes(keys, frames_per_segment: int) -> np.ndarray:
    """Smooth motion through keyframes, for examples and tests.

    keys: (N, D) values (joints, gripper, ...); returns
    ((N - 1) * frames_per_segment + 1, D): each segment eases in and out with
    smoothstep 3s² − 2s³, so velocity is zero at every keyframe.
    """
    keys = np.asarray(keys, dtype=np.float64)
    if keys.ndim != 2 or len(keys) < 2 or frames_per_segment < 1:
        raise ValueError(
            f"interpolate_keyframes: expected (N >= 2, D) keys and frames_per_segment >= 1, "
            f"found {keys.shape} and {frames_per_segment}"
        )
    s = np.linspace(0, 1, frames_per_segment, endpoint=False)
    ease = s * s * (3 - 2 * s)
    parts = [a + ease[:, None] * (b - a) for a, b in zip(keys[:-1], keys[1:])]
    return np.concatenate(parts + [keys[-1:]])


def load_trajectory(path) -> Trajectory:
    """Read a trajectory ``.npz`` (see the module docstring for the fields)."""
    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise TrajectoryError(src, "<file>", "an existing .npz file", describe_content(path))
    if not zipfile.is_zipfile(path):
        raise TrajectoryError(src, "<file>", "a NumPy .npz archive (np.savez)", describe_content(path))
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except ValueError as exc:  # object arrays would need pickle: refused
        raise TrajectoryError(src, "<file>", "plain numeric/string arrays (no pickled objects)", str(exc)) from None
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise TrajectoryError(src, "<file>", "a NumPy .npz archive", f"{type(exc).__name__}: {exc}") from None
    unknown = sorted(set(data) - set(TRAJECTORY_FIELDS))
    if unknown:
        raise TrajectoryError(
            src, unknown[0], f"only the fields {list(TRAJECTORY_FIELDS)}", f"unknown fields {unknown}"
        )
    if "keypoints" in data and "joint_names" not in data and "q" not in data:
        # a keypoint trajectory (no joints): T comes from the keypoints
        kp = data["keypoints"]
        data["joint_names"] = np.array([], dtype=str)
        data["q"] = np.zeros((kp.shape[0] if kp.ndim else 1, 0))
    for required in ("joint_names", "q", "fps"):
        if required not in data:
            raise TrajectoryError(src, required, "a required field", "missing")
    if data["joint_names"].dtype.kind not in "US":
        raise TrajectoryError(src, "joint_names", "an array of strings", f"dtype {data['joint_names'].dtype}")
    return Trajectory(
        joint_names=tuple(np.atleast_1d(data["joint_names"]).astype(str).tolist()),
        q=data["q"],
        fps=data["fps"],
        gripper=data.get("gripper"),
        gripper_names=tuple(data["gripper_names"].astype(str).tolist()) if "gripper_names" in data else None,
        base_pose=data.get("base_pose"),
        timestamps=data.get("timestamps"),
        source=src,
        keypoints=data.get("keypoints"),
    )


def save_trajectory(traj: Trajectory, path) -> Path:
    """Write ``traj`` as ``.npz`` atomically (temp file in the same folder, then rename)."""
    path = Path(path)
    arrays = {"joint_names": np.array(traj.joint_names, dtype=str), "q": traj.q, "fps": np.float64(traj.fps)}
    if traj.gripper.shape[1]:
        arrays["gripper"] = traj.gripper
    if traj.gripper_names is not None:
        arrays["gripper_names"] = np.array(traj.gripper_names, dtype=str)
    if traj.base_pose is not None:
        arrays["base_pose"] = traj.base_pose
    if traj.timestamps is not None:
        arrays["timestamps"] = traj.timestamps
    if traj.keypoints is not None:
        arrays["keypoints"] = traj.keypoints
    with atomic_output(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    return path
