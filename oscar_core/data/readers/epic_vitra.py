"""EPIC-Kitchens through VITRA's per-episode hand annotations (mano).

VITRA (microsoft/VITRA, ``data/data.md`` "Metadata Structure" and
``visualization/visualize_core.py``) publishes one pickled dict per episode,
``<metadata>/episodic_annotations/<dataset>_<video_name>_ep_<NNNNNN>.npy``::

    extrinsics          (T, 4, 4) world → camera
    intrinsics          (3, 3) pixels of the raw video (principal point at the image centre)
    video_name          the raw video (EPIC-Kitchens ``P01_01``)
    video_decode_frame  list[int]: the episode's frames in the raw video (consecutive)
    anno_type           the primary hand ("left" / "right")
    text                {"left"|"right": [(description, (start, end)), ...]}
    left, right         {"joints_camspace": (T, 21, 3) m, camera frame (x right, y down, z forward),
                         "kept_frames": (T,) 0/1 valid-reconstruction mask, "beta", "hand_pose", ...}
    avg_speed, total_rotvec_degree, total_transl_dist   (not read: the pipeline's filters measure motion themselves)

The 21 joints are MANO's joints plus five fingertip vertices reordered by
VITRA's ``libs/models/mano_wrapper.py`` (``mano_to_openpose``), i.e. the
OpenPose hand order: wrist, thumb ×4, index ×4, middle ×4, ring ×4, pinky ×4
— the order of :data:`oscar_embodiments.mano.topology.KEYPOINT_NAMES`.

Videos: EPIC-Kitchens ``<video_root>/<P01>/videos/<P01_01>.MP4`` (the
download layout), or ``<video_root>/<video_name>.mp4`` (VITRA's
visualisation layout). ``video_root`` defaults to ``<source>/videos``.

The ``.npy`` files are pickles: they are read by
:func:`oscar_core.data.readers._npy.load_npy`, which refuses every global
but numpy's array reconstructors (no code from the file runs).
:meth:`EpicVitraReader.list_episodes` parses file names only (it never opens
a file, so ``n_frames`` and ``task`` are unknown until the episode is loaded).
Frames whose ``kept_frames`` is 0 become NaN (a missing hand); a NaN in a
kept frame is a broken episode. Camera: egocentric, the VITRA intrinsics.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ...plugin.reader import Episode, EpisodeError, EpisodeRef, Reader
from ._common import episode_errors, local_root, probe_video, video_header
from ._npy import NpyPickleError, load_npy

__all__ = ["EpicVitraReader", "parse_episode_name"]

CAMERA = "egocentric"
_NAME = re.compile(r"^(?P<dataset>[^_]+)_(?P<video>.+)_ep_(?P<ep>\d+)$")


def parse_episode_name(stem: str) -> tuple[str, str, str] | None:
    """``"<dataset>_<video_name>_ep_<NNNNNN>"`` → (dataset, video_name, NNNNNN), as VITRA splits it."""
    m = _NAME.match(stem)
    return (m["dataset"], m["video"], m["ep"]) if m else None


class EpicVitraReader(Reader):
    """VITRA episode annotations of EPIC-Kitchens videos → two-hand mano trajectories, egocentric camera.

    video_root: folder of the raw EPIC-Kitchens videos (default ``<source>/videos``).
    """

    name = "epic_vitra"
    description = "EPIC-Kitchens via VITRA per-episode hand arrays (.npy) + raw MP4"
    embodiments = ("mano",)

    def __init__(self, video_root: str | None = None):
        self.video_root = video_root

    def list_episodes(self, source: str) -> Iterator[EpisodeRef]:
        root = local_root(source, self.name)
        folder = root / "episodic_annotations" if (root / "episodic_annotations").is_dir() else root
        videos = Path(self.video_root) if self.video_root else root / "videos"
        for npy in sorted(folder.glob("*.npy")):
            parsed = parse_episode_name(npy.stem)
            if parsed is None:
                continue
            dataset, video, ep = parsed
            yield EpisodeRef(
                f"epic_kitchens/{video}/{ep}",
                "epic_kitchens",
                self.name,
                "mano",
                {"states": str(npy), "video": str(_video_path(videos, video))},
                cameras=(CAMERA,),
                meta={"dataset": dataset, "video_name": video, "camera": CAMERA},
            )

    def load_episode(self, ref: EpisodeRef, registry=None) -> Episode:
        from oscar_embodiments.mano.convert import egocentric_camera, trajectory_from_keypoints

        eid, npy = ref.episode_id, Path(ref.paths["states"])
        try:
            d = load_npy(npy)
        except NpyPickleError as e:
            raise EpisodeError(eid, e.path, e.field, e.expected, e.found) from None
        if not isinstance(d, dict):
            raise EpisodeError(eid, npy, "<file>", "a pickled dict (VITRA episode_info)", type(d).__name__)
        frames = _get(d, "video_decode_frame", eid, npy)
        frames = np.asarray(frames, dtype=np.int64).reshape(-1)
        T = len(frames)
        if T < 1 or (T > 1 and not (np.diff(frames) == 1).all()):
            raise EpisodeError(
                eid,
                npy,
                "video_decode_frame",
                "consecutive frame indices of the raw video",
                f"{frames[:5].tolist()}… ({T} frames)",
            )
        kp = np.full((T, 2, 21, 3), np.nan)
        for h, side in enumerate(("left", "right")):
            hand = _get(d, side, eid, npy)
            if not isinstance(hand, dict):
                raise EpisodeError(eid, npy, side, "a dict of hand arrays", type(hand).__name__)
            joints = np.asarray(_get(hand, "joints_camspace", eid, npy, f"{side}.joints_camspace"), dtype=np.float64)
            kept = np.asarray(_get(hand, "kept_frames", eid, npy, f"{side}.kept_frames")).reshape(-1).astype(bool)
            if joints.shape != (T, 21, 3):
                raise EpisodeError(
                    eid,
                    npy,
                    f"{side}.joints_camspace",
                    f"shape ({T}, 21, 3), one row per video_decode_frame",
                    f"shape {joints.shape}",
                )
            if kept.shape != (T,):
                raise EpisodeError(eid, npy, f"{side}.kept_frames", f"shape ({T},)", f"shape {kept.shape}")
            bad = kept & ~np.isfinite(joints).all(axis=(1, 2))
            if bad.any():
                raise EpisodeError(
                    eid,
                    npy,
                    f"{side}.joints_camspace",
                    "finite joints in every kept frame",
                    f"non-finite values in {int(bad.sum())} kept frames (first {int(np.argmax(bad))})",
                )
            kp[kept, h] = joints[kept]
        K = np.asarray(_get(d, "intrinsics", eid, npy), dtype=np.float64)
        if K.shape != (3, 3) or not np.isfinite(K).all():
            raise EpisodeError(eid, npy, "intrinsics", "a finite 3x3 camera matrix (pixels)", f"shape {K.shape}")
        video_path = Path(ref.paths["video"])
        rate, width, height = video_header(eid, video_path, CAMERA, self.name)
        if not rate:
            raise EpisodeError(eid, video_path, CAMERA, "a video with a frame rate", "none")
        video = probe_video(eid, video_path, T, rate, start=float(frames[0]) / rate, field=CAMERA, reader=self.name)
        with episode_errors(eid, npy):
            traj = trajectory_from_keypoints(kp, rate, source=str(npy))
            camera = egocentric_camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], width, height)
        return Episode(ref, traj, camera, CAMERA, video, _task(d))


def _get(d: dict, key: str, eid: str, path: Path, field: str | None = None) -> Any:
    if key not in d:
        raise EpisodeError(eid, path, field or key, "a field of VITRA's episode_info", "missing")
    return d[key]


def _task(d: dict) -> str | None:
    """The primary hand's first description (``text[anno_type][0][0]``), else any."""
    text = d.get("text")
    if not isinstance(text, dict):
        return None
    order = [d.get("anno_type"), "right", "left"]
    for side in order:
        items = text.get(side) if side else None
        if items:
            first = items[0]
            return str(first[0] if isinstance(first, (list, tuple)) else first)
    return None


def _video_path(root: Path, video: str) -> Path:
    participant = video.split("_")[0]
    for cand in (
        root / participant / "videos" / f"{video}.MP4",
        root / participant / "videos" / f"{video}.mp4",
        root / f"{video}.mp4",
        root / f"{video}.MP4",
    ):
        if cand.is_file():
            return cand
    return root / participant / "videos" / f"{video}.MP4"
