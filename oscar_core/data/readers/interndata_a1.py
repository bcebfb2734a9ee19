"""InternData-A1 reader (franka): LeRobot v2.1 datasets, one per task, under a release folder.

InternData-A1 (InternRobotics) ships each task as a LeRobot v2.1 dataset,
``<release>/<category>/<robot>/<task>/{meta,data,videos}`` (layout of
:mod:`._lerobot`). Columns, written by InternData-A1's
``policy/lmdb2lerobotv21/lmdb2lerobot_franka_a1.py`` (its ``FEATURES`` table)::

    states.joint.position            (7,) rad
    states.gripper.position          (1,) finger width, m (0 closed .. 0.08 open)
    head_camera_intrinsics           (4,) [fx, fy, cx, cy] pixels of the 640x480 video
    head_camera_to_robot_extrinsics  (7,) [x, y, z, qw, qx, qy, qz] camera pose in the robot base, OpenCV axes
    timestamp                        seconds
    images.rgb.head / images.rgb.hand   videos (480, 640, 3)

:meth:`InternDataA1Reader.list_episodes` finds every ``meta/info.json``
below the source whose features hold a single 7-joint arm
(``states.joint.position`` of shape [7] and the head camera columns): the
Franka tasks. Dual-arm robots of the release (Genie-1, ALOHA, ...) have no
oscar embodiment and are skipped. Conversion:
:func:`oscar_embodiments.franka.adapters.from_interndata`. Camera: ``head``
(the static scene camera; the hand camera moves with the wrist).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

from ...plugin.reader import Episode, EpisodeError, EpisodeRef, Reader
from ._common import episode_errors, finite, local_root, probe_video
from ._lerobot import LeRobotLayout, unreadable_table

__all__ = ["InternDataA1Reader"]

COLUMNS = (
    "states.joint.position",
    "states.gripper.position",
    "head_camera_intrinsics",
    "head_camera_to_robot_extrinsics",
)
VIDEO = "images.rgb.head"


def _is_franka(info: dict) -> bool:
    f = info.get("features") or {}
    joint = f.get("states.joint.position") or {}
    return list(joint.get("shape") or []) == [7] and all(c in f for c in COLUMNS) and VIDEO in f


class InternDataA1Reader(Reader):
    """InternData-A1 Franka tasks (LeRobot v2.1) → franka trajectories seen by the head camera."""

    name = "interndata_a1"
    description = "InternData-A1: LeRobot v2.1 task datasets, Franka tasks (head camera)"
    embodiments = ("franka",)

    def list_episodes(self, source: str) -> Iterator[EpisodeRef]:
        root = local_root(source, self.name)
        for info_path in sorted(root.rglob("meta/info.json")):
            try:
                info = json.loads(info_path.read_text())
            except (OSError, ValueError):
                continue
            if not _is_franka(info):
                continue
            dataset = info_path.parent.parent
            rel = dataset.relative_to(root).as_posix() if dataset != root else dataset.name
            layout = LeRobotLayout(dataset, self.name)
            for row in layout.episodes():
                if row.error:  # one rejected row naming the broken table; the other tables' episodes go on
                    table = Path(row.data).relative_to(dataset).as_posix()
                    yield EpisodeRef(
                        f"interndata_a1/{rel}/{table}{row.error_id}",
                        "interndata_a1",
                        self.name,
                        "franka",
                        {"root": str(dataset), "states": row.data},
                        fps=layout.fps,
                        meta={"unreadable_table": row.error},
                    )
                    continue
                video = row.videos.get(VIDEO)
                yield EpisodeRef(
                    f"interndata_a1/{rel}/{row.index}",
                    "interndata_a1",
                    self.name,
                    "franka",
                    {"root": str(dataset), "data": row.data, "states": row.data, "video": video[0] if video else ""},
                    n_frames=row.length,
                    fps=layout.fps,
                    task=row.tasks[0] if row.tasks else None,
                    cameras=("head", "hand") if "images.rgb.hand" in layout.features else ("head",),
                    meta={"episode_index": row.index, "camera": "head", "video_start": video[1] if video else 0.0},
                )

    def load_episode(self, ref: EpisodeRef, registry=None) -> Episode:
        from oscar_embodiments.franka.adapters import from_interndata

        unreadable_table(ref)
        eid = ref.episode_id
        cam = ref.meta.get("camera") or "head"
        if cam != "head":
            raise EpisodeError(eid, ref.paths["data"], "camera", "'head' (the static scene camera)", repr(cam))
        layout = LeRobotLayout(Path(ref.paths["root"]), self.name)
        cols = list(COLUMNS) + (["timestamp"] if "timestamp" in layout.features else [])
        frames = layout.frames(eid, ref.paths["data"], int(ref.meta["episode_index"]), cols, ref.n_frames)
        for c in COLUMNS[:2]:
            finite(frames[c], eid, ref.paths["data"], c, "joint / gripper state")
        size = layout.image_size(VIDEO) or (640, 480)
        with episode_errors(eid, ref.paths["data"]):
            traj, camera = from_interndata(
                frames, camera="head", fps=layout.fps, image_size=size, source=ref.paths["data"]
            )
        video = probe_video(
            eid,
            Path(ref.paths["video"]),
            len(traj),
            layout.fps,
            start=float(ref.meta.get("video_start", 0.0)),
            field=VIDEO,
            reader=self.name,
        )
        return Episode(ref, traj, camera, "head", video, ref.task)
