"""What ``oscar view`` shows, gathered and checked before anything is logged.

A :class:`ViewSource` is one episode: an embodiment, its checked trajectory, the
camera (optional), the real RGB video, a generated video (a rollout) and a stored
condition video, each optional. Four ways to make one, one per kind of folder the
project writes:

- :func:`episode_source`: files given one by one (a video, a trajectory ``.npz``,
  a camera JSON, an embodiment name; ``generated`` for a rollout's video);
- :func:`clip_source`: one clip of a clip set (docs/formats.md, "Training clips");
- :func:`closed_loop_source`: a cell folder of ``oscar eval closed-loop``
  (``video.mkv``, ``condition.mkv``, ``trajectory.npz``, ``record.json``), its embodiment and camera given, or
  read from its session in the closed-loop manifest (:func:`closed_loop_cell_source`);
- :func:`eval_run_source`: one (session, policy) cell of an ``oscar eval run``
  output folder, read through its manifest.

Every check runs here: a missing file, an unknown embodiment, a video shorter
than the trajectory or a per-frame camera of another length is one
:class:`~oscar_core.errors.OscarError` naming the file, the field, what was
expected and what was found.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputFileError, OscarError

__all__ = [
    "ViewSource",
    "frames_by_time",
    "episode_source",
    "clip_source",
    "closed_loop_source",
    "closed_loop_cell_source",
    "is_closed_loop_manifest",
    "eval_run_source",
    "describe",
]


@dataclass(frozen=True)
class ViewSource:
    """One episode to view.

    name: a label (the recording's name); embodiment: the plugin instance; trajectory: checked, T frames;
    camera: the calibration or None (then no frustum and no rendered condition); rgb: the real video
    (file or PNG folder) or None; generated: a generated video (a rollout) or None; condition: a stored
    condition video or None (then it is rendered from trajectory and camera); frames: {role: frame count}
    of each video; rgb_frames: (T,) the real video's frame shown at each trajectory frame, nearest in time
    (:func:`frames_by_time`), or None.
    """

    name: str
    embodiment: object
    trajectory: object
    camera: object = None
    camera_source: str = "<camera>"
    rgb: Path | None = None
    generated: Path | None = None
    condition: Path | None = None
    frames: dict | None = None
    rgb_frames: tuple | None = None


#: Two frame rates closer than this (relative) are the same rate: a container stores a rational
#: approximation of the rate it was written at, and a video at its trajectory's rate is read frame for frame.
SAME_RATE = 1e-3


def frames_by_time(video_fps, fps: float, T: int) -> np.ndarray:
    """The video frame shown at each of ``T`` trajectory frames: (T,) int, frame ``round(t / fps * video_fps)``.

    The trajectory's frame t is at t / ``fps`` seconds, the video's frame i at i / ``video_fps`` seconds, both
    from the episode's start; the nearest video frame in time is shown (ties to the earlier). A video of
    unknown rate (a PNG folder) or at the trajectory's rate (within :data:`SAME_RATE`) is read frame for frame.
    """
    t = np.arange(T)
    if video_fps is None or abs(float(video_fps) / float(fps) - 1.0) <= SAME_RATE:
        return t
    return np.ceil(t * float(video_fps) / float(fps) - 0.5).astype(int)


def _file(path, what: str) -> Path:
    p = Path(path)
    if not p.exists():
        raise InputFileError(p, what, "an existing file", "no such file")
    return p


def _video_info(path: Path, role: str) -> dict:
    from ..media.video import video_info

    try:
        return video_info(path)
    except (ValueError, OSError) as exc:
        raise InputFileError(path, role, "a readable video or folder of PNG frames", str(exc)) from None


def episode_source(
    embodiment: str,
    trajectory,
    camera=None,
    video=None,
    generated=None,
    condition=None,
    *,
    registry=None,
    name: str | None = None,
) -> ViewSource:
    """A :class:`ViewSource` from files: ``embodiment`` is an installed embodiment's name; ``trajectory`` a
    ``.npz``; ``camera`` a camera JSON; ``video`` / ``generated`` / ``condition`` videos (files or PNG folders).

    The generated and condition videos are at the trajectory's rate and must hold at least its T frames (the
    first T are shown). The real video is shown by time (:func:`frames_by_time`): at another rate than the
    trajectory's (a RoboArena camera at 15 fps beside a trajectory resampled to 16 or 10 fps) the frame nearest
    in time is shown, and the video must last as long as the trajectory.
    """
    from ..kinematics.trajectory import load_trajectory
    from ..plugin.registry import Registry

    paths = {"trajectory": _file(trajectory, "trajectory")}
    for role, p in (("camera", camera), ("video", video), ("generated", generated), ("condition", condition)):
        if p is not None:
            paths[role] = _file(p, role)
    emb = (registry or Registry()).get(embodiment)
    traj = emb.check_trajectory(load_trajectory(paths["trajectory"]))
    cam = None
    if camera is not None:
        cam = emb.load_camera(paths["camera"])
        emb.check_camera(cam, str(paths["camera"]))
        cam.check_frames(len(traj), str(paths["camera"]))
    frames, rgb_frames = {}, None
    for role in ("video", "generated", "condition"):
        if role in paths:
            info = _video_info(paths[role], role)
            n = int(info["frames"])
            at = frames_by_time(info["fps"], traj.fps, len(traj)) if role == "video" else np.arange(len(traj))
            if n <= at[-1]:
                span = "" if at[-1] == len(traj) - 1 else f" at {info['fps']:g} fps to cover {len(traj) / traj.fps:g} s"
                raise InputFileError(
                    paths[role],
                    "frames",
                    f"at least {at[-1] + 1} frames{span} (the length of {paths['trajectory']}, "
                    f"{len(traj)} frames at {float(traj.fps):g} fps)",
                    f"{n} frames",
                )
            frames[role] = n
            if role == "video":
                rgb_frames = tuple(int(i) for i in at)
    if condition is not None and cam is None:
        raise OscarError(f"{paths['condition']}: a condition video is shown over the camera's view; give a camera too")
    return ViewSource(
        name=name or Path(trajectory).stem,
        embodiment=emb,
        trajectory=traj,
        camera=cam,
        camera_source=str(paths.get("camera", "<camera>")),
        rgb=paths.get("video"),
        generated=paths.get("generated"),
        condition=paths.get("condition"),
        frames=frames,
        rgb_frames=rgb_frames,
    )


def clip_source(root, clip_id: str, *, registry=None) -> ViewSource:
    """Clip ``clip_id`` of the clip set at ``root``: its RGB video, trajectory, camera and stored skeleton video."""
    from ..train.clips import ClipFormatError, ClipSet

    clips = ClipSet(root)
    try:
        rec = clips.record(clip_id)
    except KeyError:
        known = [r.id for r in clips][:10]
        raise ClipFormatError(root, clip_id, "id", f"a clip of the set (e.g. {known})", "no such clip") from None
    clips.read_trajectory(rec)  # every file of the record exists, the trajectory has n_frames frames
    return episode_source(
        rec.embodiment,
        clips.path(rec, "trajectory"),
        clips.path(rec, "camera"),
        clips.path(rec, "rgb"),
        condition=clips.path(rec, "skeleton") if "skeleton" in rec.files else None,
        registry=registry,
        name=rec.id,
    )


def _read_record(path: Path) -> dict:
    from .._util.json_file import read_json

    doc = read_json(path, InputFileError)
    if not isinstance(doc, dict):
        raise InputFileError(path, "<document>", "a JSON object", type(doc).__name__)
    return doc


def closed_loop_source(folder, embodiment: str, camera, *, registry=None) -> ViewSource:
    """A cell folder of ``oscar eval closed-loop`` (``OUT/cells/<session>/<policy>/``): the generated video, the
    condition video the model saw and the integrated trajectory; the camera and embodiment are its session's in
    the closed-loop manifest, given here (:func:`closed_loop_cell_source` reads them from the manifest)."""
    folder = Path(folder)
    rec = _read_record(_file(folder / "record.json", "record.json"))
    if rec.get("status") != "ok":
        raise InputFileError(
            folder / "record.json", "status", "'ok' (a failed cell has no video)", f"{rec.get('status')!r}"
        )
    cond = folder / "condition.mkv"
    return episode_source(
        embodiment,
        folder / "trajectory.npz",
        camera,
        generated=folder / "video.mkv",
        condition=cond if cond.exists() else None,
        registry=registry,
        name=f"{rec.get('session')}/{rec.get('policy')}",
    )


def is_closed_loop_manifest(path) -> bool:
    """Whether the JSON file ``path`` declares itself a closed-loop manifest (``"format":
    "oscar-closed-loop-manifest"``); a file that cannot be read is not one (its own loader says why)."""
    from ..evaluation.closed_loop_manifest import FORMAT

    try:
        import json

        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and doc.get("format") == FORMAT


def closed_loop_cell_source(folder, manifest, *, embodiment=None, camera=None, registry=None) -> ViewSource:
    """A cell folder of ``oscar eval closed-loop`` with the embodiment and camera of its session in ``manifest``
    (the closed-loop manifest the run was made from; paths in it resolve from its folder). ``embodiment`` or
    ``camera`` given here replace the session's."""
    from ..evaluation.closed_loop_manifest import load_closed_loop_manifest

    folder = Path(folder)
    rec = _read_record(_file(folder / "record.json", "record.json"))
    man = load_closed_loop_manifest(_file(manifest, "manifest"))
    found = [s for s in man.sessions if s.session == rec.get("session")]
    if not found:
        names = [s.session for s in man.sessions][:10]
        raise InputFileError(
            manifest,
            "sessions",
            f"the session of {folder / 'record.json'} (sessions: {names})",
            repr(rec.get("session")),
        )
    s = found[0]
    return closed_loop_source(folder, embodiment or s.embodiment, camera or s.camera, registry=registry)


def eval_run_source(run, manifest, cell: str, *, registry=None) -> ViewSource:
    """Cell ``cell`` (``"SESSION/POLICY"``) of the ``oscar eval run`` output folder ``run`` made from ``manifest``:
    its rollout (``run/rollouts/SESSION/POLICY.mkv``) beside its real video when the cell has one."""
    from ..evaluation.manifest import load_manifest

    man = load_manifest(_file(manifest, "manifest"))
    session, sep, policy = cell.partition("/")
    found = [c for c in man.cells if c.session == session and c.policy == policy]
    if not sep or not found:
        names = [f"{c.session}/{c.policy}" for c in man.cells][:10]
        raise InputFileError(manifest, "cells", f"a cell SESSION/POLICY of the manifest (e.g. {names})", repr(cell))
    c = found[0]
    rollout = Path(run) / "rollouts" / session / f"{policy}.mkv"
    if not rollout.exists():
        raise InputFileError(rollout, "rollout", f"the rollout of cell {cell} (run oscar eval run first)", "no file")
    return episode_source(
        c.embodiment,
        c.trajectory,
        c.camera,
        c.real_video,
        generated=rollout,
        registry=registry,
        name=cell,
    )


def describe(source: ViewSource) -> dict:
    """JSON-ready summary of what a source holds."""
    return {
        "name": source.name,
        "embodiment": source.embodiment.name,
        "frames": len(source.trajectory),
        "fps": float(source.trajectory.fps),
        "camera": None if source.camera is None else source.camera_source,
        **{k: None if v is None else str(v) for k, v in (("video", source.rgb), ("generated", source.generated))},
        "condition": None if source.condition is None else str(source.condition),
    }
