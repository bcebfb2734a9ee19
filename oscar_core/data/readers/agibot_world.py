"""AgiBot World reader (agibot_g1): ``proprio_stats.h5`` + camera JSONs + per-episode MP4s.

Layout of AgiBot World Alpha/Beta (dataset card of
``agibot-world/AgiBotWorld-Alpha`` and the AgiBot-World repository's docs;
field meanings in :mod:`oscar_embodiments.agibot_g1.adapters`)::

    task_info/task_<task>.json                         [{"episode_id", "task_name", "init_scene_text", ...}]
    observations/<task>/<episode>/videos/<camera>.mp4  head_color, hand_left_color, hand_right_color, ...
    proprio_stats/<task>/<episode>/proprio_stats.h5    state/joint/position (N, 14) rad,
                                                       state/waist/position (N, 2), state/head/position (N, 2),
                                                       action/effector/position (N', 2) 0 open .. 1 closed,
                                                       timestamp (N,) ns
    parameters/<task>/<episode>/parameters/camera/     head_intrinsic_params.json,
                                                       head_extrinsic_params_aligned.json (per frame)

:meth:`AgiBotWorldReader.list_episodes` globs the ``proprio_stats.h5``
files and reads only the shape of ``state/joint/position`` (the h5 header)
and the task JSON. :meth:`~AgiBotWorldReader.load_episode` reads the
arrays through :func:`oscar_embodiments.agibot_g1.adapters.load_agibot_world_episode`
and converts them with :func:`~oscar_embodiments.agibot_g1.adapters.from_agibot_world`.

Camera: ``head_color`` (the head camera, the only view whose calibration
AgiBot World ships; the robot's skeleton is drawn from it).

Known defect — ``action/effector/position`` longer (or shorter) than the
states in some tasks: the action rows cannot be matched to state frames
without a shared clock, so such an episode is **rejected** with an
:class:`~oscar_core.plugin.reader.EpisodeError` naming both lengths (field
``action/effector/position``), and the run counts it.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from ...plugin.reader import Episode, EpisodeError, EpisodeRef, Reader
from ._common import episode_errors, finite, local_root, probe_video, read_json, require

__all__ = ["AgiBotWorldReader"]

STATE = "state/joint/position"
GRIPPER = "action/effector/position"
CAMERA = "head_color"
CAMERA_FILES = ("head_intrinsic_params", "head_extrinsic_params_aligned")


class AgiBotWorldReader(Reader):
    """AgiBot World (Alpha/Beta) episodes → agibot_g1 trajectories seen by the head camera."""

    name = "agibot_world"
    description = "AgiBot World: proprio_stats.h5 + camera JSONs + head_color.mp4"
    embodiments = ("agibot_g1",)

    def list_episodes(self, source: str) -> Iterator[EpisodeRef]:
        h5py = require("h5py", self.name)
        root = local_root(source, self.name)
        tasks: dict[str, dict] = {}
        for h5 in sorted((root / "proprio_stats").glob("*/*/proprio_stats.h5")):
            task, episode = h5.parent.parent.name, h5.parent.name
            if task not in tasks:
                tasks[task] = _task_texts(root / "task_info" / f"task_{task}.json")
            n = None
            try:
                with h5py.File(h5, "r") as f:
                    if STATE in f:
                        n = int(f[STATE].shape[0])
            except OSError:
                pass  # a broken file is reported by load_episode, with its reason
            videos = root / "observations" / task / episode / "videos"
            names = sorted(p.stem for p in videos.glob("*.mp4"))
            cams = tuple([CAMERA] + [c for c in names if c != CAMERA])
            yield EpisodeRef(
                f"agibot_world/{task}/{episode}",
                "agibot_world",
                self.name,
                "agibot_g1",
                {
                    "root": str(root),
                    "states": str(h5),
                    "video": str(videos / f"{CAMERA}.mp4"),
                    "calibration": str(root / "parameters" / task / episode / "parameters" / "camera"),
                },
                n_frames=n,
                fps=None,
                task=tasks[task].get(episode),
                cameras=cams,
                meta={"task_id": task, "episode": episode, "camera": CAMERA},
            )

    def load_episode(self, ref: EpisodeRef, registry=None) -> Episode:
        require("h5py", self.name)
        from oscar_embodiments.agibot_g1.adapters import from_agibot_world, load_agibot_world_episode

        eid, h5 = ref.episode_id, Path(ref.paths["states"])
        cam = ref.meta.get("camera") or CAMERA
        if cam != CAMERA:
            raise EpisodeError(
                eid, ref.paths["calibration"], "camera", f"{CAMERA!r} (the only calibrated view)", repr(cam)
            )
        root, task, episode = Path(ref.paths["root"]), ref.meta["task_id"], ref.meta["episode"]
        for name in CAMERA_FILES:  # name the missing file before the adapter's loader does
            folders = [
                root / "parameters" / task / episode / "parameters" / "camera",
                root / "parameters" / task / episode / "camera",
            ]
            if not any((d / f"{name}.json").is_file() for d in folders):
                raise EpisodeError(
                    eid, folders[0] / f"{name}.json", "<file>", "the head camera calibration", "no such file"
                )
            for d in folders:
                if (d / f"{name}.json").is_file():
                    read_json(d / f"{name}.json", eid, "the head camera calibration")  # malformed → EpisodeError
                    break
        if not h5.is_file():
            raise EpisodeError(eid, h5, "<file>", "proprio_stats.h5", "no such file")
        with episode_errors(eid, h5):
            record = load_agibot_world_episode(root, task, episode, gripper_key=GRIPPER)
        for key in (STATE, "state/waist/position", "state/head/position", GRIPPER):
            if key not in record:
                raise EpisodeError(eid, h5, key, "a dataset in proprio_stats.h5", "missing")
            finite(record[key], eid, h5, key, "joint / gripper values")
        n, m = len(record[STATE]), len(record[GRIPPER])
        if n != m:
            raise EpisodeError(
                eid,
                h5,
                GRIPPER,
                f"{n} rows, one per state frame (state/joint/position); AgiBot World's "
                "known action/state length defect: episode rejected",
                f"{m} rows",
            )
        with episode_errors(eid, h5):
            traj, camera = from_agibot_world(record, source=str(h5))
        video = probe_video(eid, Path(ref.paths["video"]), len(traj), None, field=cam, reader=self.name)
        return Episode(ref, traj, camera, cam, video, ref.task)


def _task_texts(path: Path) -> dict[str, str]:
    """episode id → task text from ``task_info/task_<task>.json`` (empty when absent or malformed)."""
    import json

    try:
        items = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    out = {}
    for item in items if isinstance(items, list) else []:
        if isinstance(item, dict) and "episode_id" in item:
            out[str(item["episode_id"])] = str(item.get("task_name") or item.get("init_scene_text") or "") or None
    return out
