"""The generic reader: one folder per episode holding oscar's own files.

Layout (``SOURCE`` is a local folder or fsspec URL)::

    SOURCE/<episode>/episode.json     {"embodiment": "franka", "task": "...", "source": "mydata", "camera": "front"}
    SOURCE/<episode>/trajectory.npz   the trajectory (docs/formats.md), T frames
    SOURCE/<episode>/camera.json      the camera calibration (docs/formats.md)
    SOURCE/<episode>/rgb.mp4          the video (or rgb.mkv), T frames at the trajectory's fps

``embodiment`` is required; ``source`` defaults to the name of ``SOURCE``,
``camera`` to ``"main"``, ``task`` to none. Episode ids are
``<source>/<episode folder>``. Loading needs local files (a local path or a
``file://`` URL): the video is decoded with PyAV from disk.
"""

from __future__ import annotations

import json
import posixpath

from ...plugin.reader import Episode, EpisodeError, EpisodeRef, Reader, VideoSource

__all__ = ["NpzReader"]


class NpzReader(Reader):
    name = "npz"
    description = "one folder per episode: episode.json, trajectory.npz, camera.json, rgb.mp4 (oscar's own formats)"
    embodiments = ()

    def list_episodes(self, source: str):
        from .. import _fs

        fs, root = _fs.url_to_fs(source)
        if not fs.isdir(root):
            raise FileNotFoundError(f"{source}: expected a folder of episode folders, found no such folder")
        base = source.rstrip("/")
        default_source = posixpath.basename(root.rstrip("/")) or "npz"
        for meta_path in sorted(fs.glob(posixpath.join(root, "*", "episode.json"))):
            folder = posixpath.basename(posixpath.dirname(meta_path))
            where = _fs.join(base, folder)
            try:
                with fs.open(meta_path, "rb") as f:
                    meta = json.loads(f.read())
            except (OSError, ValueError) as exc:
                raise EpisodeError(
                    f"{default_source}/{folder}", meta_path, "<file>", "a JSON object", str(exc)
                ) from None
            if not isinstance(meta, dict) or not isinstance(meta.get("embodiment"), str):
                raise EpisodeError(
                    f"{default_source}/{folder}",
                    meta_path,
                    "embodiment",
                    "an embodiment name",
                    repr(meta.get("embodiment") if isinstance(meta, dict) else meta),
                )
            src = str(meta.get("source") or default_source)
            names = set(posixpath.basename(p) for p in fs.ls(posixpath.dirname(meta_path), detail=False))
            video = "rgb.mkv" if "rgb.mkv" in names and "rgb.mp4" not in names else "rgb.mp4"
            paths = {
                "trajectory": _fs.join(where, "trajectory.npz"),
                "camera": _fs.join(where, "camera.json"),
                "video": _fs.join(where, video),
                "episode": _fs.join(where, "episode.json"),
            }
            yield EpisodeRef(
                episode_id=f"{src}/{folder}",
                source=src,
                reader=self.name,
                embodiment=meta["embodiment"],
                paths=paths,
                n_frames=meta.get("n_frames"),
                fps=meta.get("fps"),
                task=meta.get("task"),
                cameras=(str(meta.get("camera") or "main"),),
            )

    def load_episode(self, ref: EpisodeRef, registry=None) -> Episode:
        from pathlib import Path

        from ...errors import OscarError
        from ...kinematics.trajectory import load_trajectory
        from ...plugin.registry import default_registry
        from .. import _fs

        reg = registry or default_registry()
        local = {role: Path(_fs.local_path(url)) for role, url in ref.paths.items()}
        for role in ("trajectory", "camera", "video"):
            if not local[role].is_file():
                raise EpisodeError(ref.episode_id, ref.paths[role], role, f"a {role} file", "no such file")
        emb = reg.get(ref.embodiment)
        try:
            traj = emb.check_trajectory(load_trajectory(local["trajectory"]))
        except OscarError as exc:
            raise EpisodeError(
                ref.episode_id,
                ref.paths["trajectory"],
                getattr(exc, "field", "trajectory"),
                getattr(exc, "expected", "a valid trajectory"),
                getattr(exc, "found", str(exc)),
            ) from None
        try:
            cam = emb.load_camera(local["camera"])
            emb.check_camera(cam, str(local["camera"]))
        except OscarError as exc:
            raise EpisodeError(
                ref.episode_id,
                ref.paths["camera"],
                getattr(exc, "field", "camera"),
                getattr(exc, "expected", "a valid camera"),
                getattr(exc, "found", str(exc)),
            ) from None
        video = VideoSource(str(local["video"]), n_frames=len(traj), fps=float(traj.fps))
        return Episode(
            ref=ref,
            trajectory=traj,
            camera=cam,
            camera_name=ref.cameras[0] if ref.cameras else "main",
            video=video,
            task=ref.task,
        )
