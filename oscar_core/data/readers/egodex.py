"""EgoDex reader (mano): ``<part>/<task>/<n>.hdf5`` + ``<n>.mp4``.

Field names from the EgoDex README (apple/ml-egodex) and the HDF5 files
themselves (hand joints are ARKit/visionOS ``HandSkeleton`` joint names)::

    camera/intrinsic        (3, 3) pixels of the 1920x1080 video
    transforms/camera       (T, 4, 4) camera pose in the ARKit world (camera → world),
                            ARKit camera axes: x right, y up, looking along -z ("opengl")
    transforms/<joint>      (T, 4, 4) joint pose in the world; joints per hand
                            (<side> = left | right): <side>Hand (wrist),
                            <side>ThumbKnuckle, ...ThumbIntermediateBase, ...ThumbIntermediateTip, ...ThumbTip,
                            <side>{Index,Middle,Ring,Little}Finger{Metacarpal,Knuckle,IntermediateBase,IntermediateTip,Tip}
    confidences/<joint>     (T,) ARKit tracking confidence in [0, 1] (optional)
    attrs: llm_description  the task text
    <n>.mp4                 30 fps, frame i ↔ row i

Keypoint mapping to oscar's 21 points per hand (``topology.KEYPOINT_NAMES``):
wrist ← ``Hand``; thumb cmc/mcp/ip/tip ← ``ThumbKnuckle``/``IntermediateBase``/
``IntermediateTip``/``Tip``; finger mcp/pip/dip/tip ← ``Knuckle``/
``IntermediateBase``/``IntermediateTip``/``Tip`` (the ``Metacarpal`` joints
have no oscar point); pinky ← ``Little``. The world-frame points are moved
into each frame's camera frame with the per-frame camera pose by
:func:`oscar_embodiments.mano.convert.trajectory_from_keypoints`, and drawn
with the dataset's intrinsics by :func:`~oscar_embodiments.mano.convert.egocentric_camera`
(egocentric, as the paper uses for humans).

Points whose confidence is below ``min_confidence`` (default 0: keep all)
become NaN (a missing point). A NaN/inf stored in a transform is a broken
episode (:class:`~oscar_core.plugin.reader.EpisodeError`).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ...errors import InputFileError
from ...plugin.reader import Episode, EpisodeError, EpisodeRef, Reader
from ._common import episode_errors, finite, local_root, probe_video, require, video_header

__all__ = ["EgoDexReader", "EGODEX_JOINTS", "egodex_joint_names"]

_FINGER = {"index": "Index", "middle": "Middle", "ring": "Ring", "pinky": "Little"}
_PARTS = ("Knuckle", "IntermediateBase", "IntermediateTip", "Tip")


def egodex_joint_names(side: str) -> tuple[str, ...]:
    """The 21 EgoDex transform names of one hand (``"left"``/``"right"``) in oscar's keypoint order."""
    names = [f"{side}Hand"] + [f"{side}Thumb{p}" for p in _PARTS]
    for finger in ("index", "middle", "ring", "pinky"):
        names += [f"{side}{_FINGER[finger]}Finger{p}" for p in _PARTS]
    return tuple(names)


#: hand → 21 transform names, oscar keypoint order
EGODEX_JOINTS = {"left": egodex_joint_names("left"), "right": egodex_joint_names("right")}
EGODEX_FPS = 30.0
CAMERA = "egocentric"


class EgoDexReader(Reader):
    """EgoDex episodes → two-hand mano trajectories in the egocentric camera."""

    name = "egodex"
    description = "EgoDex: HDF5 ARKit transforms + MP4 (egocentric)"
    embodiments = ("mano",)

    def __init__(self, min_confidence: float = 0.0, camera_convention: str = "opengl"):
        self.min_confidence = float(min_confidence)
        self.camera_convention = camera_convention

    def list_episodes(self, source: str) -> Iterator[EpisodeRef]:
        h5py = require("h5py", self.name)
        root = local_root(source, self.name)
        for h5 in sorted(root.rglob("*.hdf5")):
            rel = h5.relative_to(root).with_suffix("").as_posix()
            n, task = None, None
            try:
                with h5py.File(h5, "r") as f:
                    if "transforms/camera" in f:
                        n = int(f["transforms/camera"].shape[0])
                    text = f.attrs.get("llm_description")
                    task = text.decode() if isinstance(text, bytes) else (str(text) if text is not None else None)
            except OSError:
                pass  # reported by load_episode
            yield EpisodeRef(
                f"egodex/{rel}",
                "egodex",
                self.name,
                "mano",
                {"states": str(h5), "video": str(h5.with_suffix(".mp4"))},
                n_frames=n,
                fps=EGODEX_FPS,
                task=task or h5.parent.name.replace("_", " "),
                cameras=(CAMERA,),
                meta={"camera": CAMERA},
            )

    def load_episode(self, ref: EpisodeRef, registry=None) -> Episode:
        h5py = require("h5py", self.name)
        from oscar_embodiments.mano.convert import egocentric_camera, trajectory_from_keypoints

        eid, h5 = ref.episode_id, Path(ref.paths["states"])
        if not h5.is_file():
            raise EpisodeError(eid, h5, "<file>", "the episode's .hdf5", "no such file")
        with episode_errors(eid, h5):
            with h5py.File(h5, "r") as f:
                K = finite(_dataset(f, "camera/intrinsic", eid, h5), eid, h5, "camera/intrinsic", "a 3x3 camera matrix")
                cam = finite(
                    _dataset(f, "transforms/camera", eid, h5), eid, h5, "transforms/camera", "(T, 4, 4) camera poses"
                )
                T = len(cam)
                kp = np.empty((T, 2, 21, 3))
                for h, side in enumerate(("left", "right")):
                    for k, joint in enumerate(EGODEX_JOINTS[side]):
                        key = f"transforms/{joint}"
                        M = finite(_dataset(f, key, eid, h5), eid, h5, key, "(T, 4, 4) joint poses")
                        if M.shape != (T, 4, 4):
                            raise EpisodeError(
                                eid, h5, key, f"shape ({T}, 4, 4), as transforms/camera", f"shape {M.shape}"
                            )
                        kp[:, h, k] = M[:, :3, 3]
                        ckey = f"confidences/{joint}"
                        if self.min_confidence > 0 and ckey in f:
                            conf = np.asarray(f[ckey][()], dtype=np.float64).reshape(-1)
                            if conf.shape == (T,):
                                kp[conf < self.min_confidence, h, k] = np.nan
        if K.shape != (3, 3):
            raise EpisodeError(eid, h5, "camera/intrinsic", "a 3x3 camera matrix (pixels)", f"shape {K.shape}")
        if cam.shape != (T, 4, 4):
            raise EpisodeError(eid, h5, "transforms/camera", "shape (T, 4, 4)", f"shape {cam.shape}")
        rate, width, height = video_header(eid, Path(ref.paths["video"]), CAMERA, self.name)
        video = probe_video(eid, Path(ref.paths["video"]), T, rate or EGODEX_FPS, field=CAMERA, reader=self.name)
        try:
            traj = trajectory_from_keypoints(
                kp, video.fps, camera_poses=cam, camera_convention=self.camera_convention, source=str(h5)
            )
        except InputFileError as e:
            raise EpisodeError(eid, e.path, e.field, e.expected, e.found) from None
        except ValueError as e:  # the mano converter's plain errors name the field in the message
            field = "transforms/camera" if "camera_poses" in str(e) else "transforms"
            raise EpisodeError(eid, h5, field, "rigid camera poses and finite keypoints", str(e)) from None
        with episode_errors(eid, h5):
            camera = egocentric_camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], width, height)
        return Episode(ref, traj, camera, CAMERA, video, ref.task)


def _dataset(f, key: str, eid: str, path: Path):
    if key not in f:
        raise EpisodeError(eid, path, key, "a dataset in the EgoDex .hdf5", "missing")
    return f[key][()]
