"""DROID raw release reader (franka_robotiq: Panda arm + Robotiq 2F-85): ``trajectory.h5`` + ``metadata_*.json`` + ``recordings/MP4/<serial>.mp4``.

Layout of one episode folder (``<lab>/success|failure/<date>/<time>/``) in
the raw DROID release, as written by ``droid/trajectory_utils/trajectory_writer.py``
and described in the DROID repository's README / dataset docs::

    trajectory.h5           observation/robot_state/joint_positions (T, 7) rad
                            observation/robot_state/gripper_position (T,) 0 open .. 1 closed
                            observation/camera_extrinsics/<serial>_left (T, 6) [x, y, z, roll, pitch, yaw]
                                camera pose in the robot base, metres / radians, scipy "xyz" Euler
                            observation/camera_intrinsics/<serial>_left (T, 3, 3) when recorded
    metadata_<uuid>.json    ext1_cam_serial, ext2_cam_serial, wrist_cam_serial, current_task,
                            trajectory_length, success
    recordings/MP4/<serial>.mp4   the left image of each ZED camera

:meth:`DroidRawReader.list_episodes` reads only the metadata JSON (no h5, no
video). :meth:`~DroidRawReader.load_episode` reads the h5 datasets it needs
and converts them with :func:`oscar_embodiments.franka.adapters.from_droid`
(15 Hz, ``DROID_FPS``). Frames are taken at the trajectory's times (frame i
at i / 15 s), whatever the MP4's own rate.

Camera: the first external camera, ``<ext1_cam_serial>_left`` (third-person,
as the paper uses for robots); ``ref.meta["camera"]`` may name
``<ext2_cam_serial>_left``. The wrist camera moves with the hand and is not
offered. Intrinsics come from ``observation/camera_intrinsics`` when the file
has them, else from ``DroidRawReader(intrinsics={serial: (fx, fy, cx, cy)})``
(e.g. a community calibration), else the episode is rejected naming the field.
Images are 1280x720 (ZED HD720) unless ``image_size=`` says otherwise.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ...plugin.reader import Episode, EpisodeError, EpisodeRef, Reader
from ._common import episode_errors, finite, local_root, probe_video, read_json, require

__all__ = ["DroidRawReader"]

JOINTS = "observation/robot_state/joint_positions"
GRIPPER = "observation/robot_state/gripper_position"


class DroidRawReader(Reader):
    """DROID raw episodes → franka_robotiq trajectories seen by an external ZED camera."""

    name = "droid_raw"
    description = "DROID raw release: trajectory.h5 + metadata JSON + recordings/MP4"
    embodiments = ("franka_robotiq",)

    def __init__(self, intrinsics: dict[str, Any] | None = None, image_size: tuple[int, int] = (1280, 720)):
        self.intrinsics = dict(intrinsics or {})
        self.image_size = tuple(image_size)

    def list_episodes(self, source: str) -> Iterator[EpisodeRef]:
        root = local_root(source, self.name)
        for h5 in sorted(root.rglob("trajectory.h5")):
            folder = h5.parent
            rel = folder.relative_to(root).as_posix() or folder.name
            metas = sorted(folder.glob("metadata*.json"))
            meta = {}
            if metas:
                try:
                    meta = read_json(metas[0], f"droid/{rel}", "episode metadata")
                except EpisodeError:
                    meta = {}
            cams = tuple(f"{meta[k]}_left" for k in ("ext1_cam_serial", "ext2_cam_serial") if meta.get(k))
            n = meta.get("trajectory_length")
            paths = {"states": str(h5), "metadata": str(metas[0]) if metas else ""}
            for c in cams:
                paths[f"video:{c}"] = str(folder / "recordings" / "MP4" / f"{c.rsplit('_', 1)[0]}.mp4")
            if cams:
                paths["video"] = paths[f"video:{cams[0]}"]  # the default camera's file
            yield EpisodeRef(
                f"droid/{rel}",
                "droid",
                self.name,
                "franka_robotiq",
                paths,
                n_frames=int(n) if isinstance(n, (int, float)) else None,
                fps=15.0,
                task=meta.get("current_task") or None,
                cameras=cams,
                meta={"camera": cams[0] if cams else None, "success": meta.get("success")},
            )

    def load_episode(self, ref: EpisodeRef, registry=None) -> Episode:
        h5py = require("h5py", self.name)
        from oscar_embodiments.franka.adapters import DROID_FPS, from_droid

        eid, h5 = ref.episode_id, Path(ref.paths["states"])
        if not ref.paths.get("metadata"):
            raise EpisodeError(
                eid, h5.parent / "metadata_<uuid>.json", "<file>", "the episode metadata JSON", "no such file"
            )
        cam = ref.meta.get("camera")
        if not cam or f"video:{cam}" not in ref.paths:
            raise EpisodeError(
                eid,
                ref.paths["metadata"],
                "ext1_cam_serial",
                f"an external camera serial (cameras listed: {list(ref.cameras)})",
                repr(cam),
            )
        serial = cam.rsplit("_", 1)[0]
        if not h5.is_file():
            raise EpisodeError(eid, h5, "<file>", "trajectory.h5", "no such file")
        with episode_errors(eid, h5):
            with h5py.File(h5, "r") as f:
                record = {}
                for key in (JOINTS, GRIPPER, f"observation/camera_extrinsics/{cam}"):
                    if key not in f:
                        raise EpisodeError(eid, h5, key, "a dataset in trajectory.h5", "missing")
                    record[key] = finite(f[key][()], eid, h5, key, "robot state / calibration")
                ikey = f"observation/camera_intrinsics/{cam}"
                K = f[ikey][()] if ikey in f else None
        if K is None:
            K = ref.meta.get("intrinsics") or self.intrinsics.get(serial) or self.intrinsics.get(cam)
        if K is None:
            raise EpisodeError(
                eid,
                h5,
                f"observation/camera_intrinsics/{cam}",
                "the camera matrix (or DroidRawReader(intrinsics={serial: (fx, fy, cx, cy)}))",
                "missing",
            )
        n = len(record[JOINTS])
        if len(record[GRIPPER]) != n:
            raise EpisodeError(
                eid, h5, GRIPPER, f"{n} rows, one per joint_positions row", f"{len(record[GRIPPER])} rows"
            )
        with episode_errors(eid, h5):
            traj, camera = from_droid(record, cam, intrinsics=K, image_size=self.image_size, source=str(h5))
        video = probe_video(eid, Path(ref.paths[f"video:{cam}"]), len(traj), DROID_FPS, field=cam, reader=self.name)
        return Episode(ref, traj, camera, cam, video, ref.task)
