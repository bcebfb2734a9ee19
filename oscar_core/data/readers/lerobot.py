"""LeRobot dataset v3.0 reader: DROID (franka_robotiq: the Panda arm with the Robotiq 2F-85 DROID mounts) and AIROA-MoMa (hsr) as published on the Hub.

Layout (see :mod:`._lerobot` for every field and where its name comes from):
``meta/info.json``, ``meta/episodes/chunk-XXX/file-YYY.parquet`` (one row per
episode, with the time range of the episode inside each shared MP4),
``data/chunk-XXX/file-YYY.parquet`` (frames of many episodes),
``videos/<camera key>/chunk-XXX/file-YYY.mp4`` (many episodes per file).
v2.1 datasets (one parquet and one MP4 per episode) are read too.

The dataset's profile is recognised from ``meta/info.json`` features:

``droid`` (``lerobot/droid_1.0.1``; columns from lerobot's
``examples/port_datasets/port_droid.py``)
    ``observation.state.joint_position`` (T, 7) rad,
    ``observation.state.gripper_position`` (T, 1) Robotiq position 0 open .. 1 closed,
    ``camera_extrinsics.<cam>`` (T, 6) ``[x, y, z, roll, pitch, yaw]`` camera
    pose in the robot base (as DROID raw), videos
    ``observation.images.<cam>`` (180x320, 15 fps). No intrinsics are
    published: pass ``intrinsics={cam: (fx, fy, cx, cy)}`` (pixels of the
    stored video) to the reader, or put ``"intrinsics"`` in ``ref.meta``;
    without them :meth:`load_episode` raises :class:`EpisodeError` naming the
    field. A dataset that ships them may put them in ``meta/info.json`` as
    ``features[<video key>]["info"]["camera.intrinsics"]`` (``[fx, fy, cx,
    cy]``; ``oscar data sample-dataset`` does). Converted by
    :func:`oscar_embodiments.franka.adapters.from_droid`.
    Default camera: ``exterior_1_left`` (third-person, as the paper).
``airoa_moma`` (``airoa-org/airoa-moma``)
    ``observation.state`` named by ``features["observation.state"]["names"]``
    (HSR joints incl. ``hand_motor_joint``), ``timestamp``, head camera video
    (first video key containing ``head``, the egocentric view the robot's
    skeleton is drawn in). Converted by
    :func:`oscar_embodiments.hsr.adapters.from_airoa_moma` (nominal head
    intrinsics: the dataset ships none).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ...plugin.reader import Episode, EpisodeError, EpisodeRef, Reader
from ._common import episode_errors, finite, local_root, probe_video
from ._lerobot import LeRobotLayout, unreadable_table

__all__ = ["LeRobotReader", "PROFILES"]

DROID_STATE = ("observation.state.joint_position", "observation.state.gripper_position")
#: profile → (source name, embodiment)
PROFILES = {"droid": ("droid", "franka_robotiq"), "airoa_moma": ("airoa_moma", "hsr")}


def _profile(layout: LeRobotLayout) -> str:
    f = layout.features
    if all(k in f for k in DROID_STATE):
        return "droid"
    names = (f.get("observation.state") or {}).get("names")
    flat = str(names)
    if "arm_lift_joint" in flat or str(layout.info.get("robot_type", "")).lower() in ("hsr", "hsrb"):
        return "airoa_moma"
    raise ValueError(
        f"{layout.info_path}: field 'features': expected a DROID ({', '.join(DROID_STATE)}) or "
        f"AIROA-MoMa (observation.state named with HSR joints) LeRobot dataset, found features "
        f"{sorted(f)[:12]} and robot_type {layout.info.get('robot_type')!r}"
    )


def _default_camera(profile: str, keys: list[str]) -> str | None:
    if profile == "droid":
        want = "observation.images.exterior_1_left"
        return want if want in keys else next((k for k in keys if "exterior" in k), None)
    return next((k for k in keys if "head" in k), keys[0] if keys else None)


class LeRobotReader(Reader):
    """LeRobot v3.0 (and v2.1) datasets: DROID → franka_robotiq, AIROA-MoMa → hsr.

    intrinsics: camera short name (``exterior_1_left``) or full video key →
    ``(fx, fy, cx, cy)`` in pixels of the stored video, for DROID (which
    publishes none).
    """

    name = "lerobot"
    description = "LeRobot dataset v3.0/v2.1 (parquet + shared MP4s): DROID, AIROA-MoMa"
    embodiments = ("franka_robotiq", "hsr")

    def __init__(self, intrinsics: dict[str, Any] | None = None):
        self.intrinsics = dict(intrinsics or {})

    def list_episodes(self, source: str) -> Iterator[EpisodeRef]:
        root = local_root(source, self.name)
        layout = LeRobotLayout(root, self.name)
        profile = _profile(layout)
        src, emb = PROFILES[profile]
        keys = layout.video_keys
        default = _default_camera(profile, keys)
        cams = tuple(([default] if default else []) + [k for k in keys if k != default])
        for row in layout.episodes():
            if row.error:  # one rejected row naming the broken table; the other tables' episodes go on
                rel = Path(row.data).relative_to(root).as_posix()
                yield EpisodeRef(
                    f"{src}/{rel}{row.error_id}",
                    src,
                    self.name,
                    emb,
                    {"root": str(root), "states": row.data},
                    fps=layout.fps,
                    cameras=cams,
                    meta={"unreadable_table": row.error},
                )
                continue
            paths = {"root": str(root), "data": row.data, "states": row.data}
            if default in row.videos:
                paths["video"] = row.videos[default][0]  # the default camera's (shared) file
            paths.update({f"video:{k}": p for k, (p, _) in row.videos.items()})
            meta = {
                "profile": profile,
                "episode_index": row.index,
                "camera": default,
                "video_start": {k: s for k, (_, s) in row.videos.items()},
            }
            yield EpisodeRef(
                f"{src}/{row.index}",
                src,
                self.name,
                emb,
                paths,
                n_frames=row.length,
                fps=layout.fps,
                task=row.tasks[0] if row.tasks else None,
                cameras=cams,
                meta=meta,
            )

    def load_episode(self, ref: EpisodeRef, registry=None) -> Episode:
        unreadable_table(ref)
        root = Path(ref.paths["root"])
        layout = LeRobotLayout(root, self.name)
        profile = ref.meta.get("profile") or _profile(layout)
        cam = ref.meta.get("camera") or _default_camera(profile, layout.video_keys)
        if cam not in layout.video_keys:
            raise EpisodeError(
                ref.episode_id,
                layout.info_path,
                "features",
                f"a video feature {cam!r}",
                f"video keys {layout.video_keys}",
            )
        index = int(ref.meta["episode_index"])
        data = ref.paths["data"]
        if profile == "droid":
            traj, camera = self._droid(ref, layout, data, index, cam)
        else:
            traj, camera = self._moma(ref, layout, data, index)
        vpath = ref.paths.get(f"video:{cam}")
        start = float((ref.meta.get("video_start") or {}).get(cam, 0.0))
        video = probe_video(
            ref.episode_id, Path(vpath), len(traj), layout.fps, start=start, field=cam, reader=self.name
        )
        return Episode(ref, traj, camera, cam, video, ref.task)

    # ------------------------------------------------------------------ profiles

    def _droid(self, ref, layout, data, index, cam):
        from oscar_embodiments.franka.adapters import from_droid

        short = cam.split(".")[-1]
        ext_col = f"camera_extrinsics.{short}"
        cols = layout.frames(ref.episode_id, data, index, list(DROID_STATE) + [ext_col], ref.n_frames)
        for c in DROID_STATE:
            finite(cols[c], ref.episode_id, data, c, "joint / gripper state")
        K = (
            ref.meta.get("intrinsics")
            or self.intrinsics.get(short)
            or self.intrinsics.get(cam)
            or ((layout.features.get(cam) or {}).get("info") or {}).get("camera.intrinsics")
        )
        if K is None:
            raise EpisodeError(
                ref.episode_id,
                layout.info_path,
                f"intrinsics of {cam}",
                "(fx, fy, cx, cy) in pixels: DROID on the Hub publishes none; pass "
                "LeRobotReader(intrinsics={'" + short + "': (fx, fy, cx, cy)}) or ref.meta['intrinsics']",
                "none",
            )
        size = layout.image_size(cam) or (320, 180)
        record = {
            "observation/joint_position": cols[DROID_STATE[0]],
            "observation/gripper_position": cols[DROID_STATE[1]],
        }
        with episode_errors(ref.episode_id, data):
            return from_droid(
                record, short, extrinsic=cols[ext_col], intrinsics=K, image_size=size, fps=layout.fps, source=data
            )

    def _moma(self, ref, layout, data, index):
        from oscar_embodiments.hsr.adapters import from_airoa_moma

        cols = ["observation.state"] + (["timestamp"] if "timestamp" in layout.features else [])
        got = layout.frames(ref.episode_id, data, index, cols, ref.n_frames)
        finite(got["observation.state"], ref.episode_id, data, "observation.state", "joint positions")
        record = {"observation.state": got["observation.state"], "info": layout.info}
        if "timestamp" in got:
            record["timestamp"] = got["timestamp"] - got["timestamp"][0]
        with episode_errors(ref.episode_id, data):
            return from_airoa_moma(record, fps=layout.fps, source=data)
