"""RH20T reader: cfg5 (Franka, franka) and cfg7 (KUKA LBR iiwa 14 + Robotiq 2F-85, kuka).

Layout of the RH20T release (``rh20t_api/scene.py``: ``RH20TScene``; the
resized release adds one MP4 and a ``timestamps.npy`` per camera)::

    RH20T_cfg<N>/calib/<t>/intrinsics.npy     {serial: 3x4 camera matrix} (1280x720 pixels)
    RH20T_cfg<N>/calib/<t>/extrinsics.npy     {serial: (1, 4, 4) marker board → camera}
    RH20T_cfg<N>/calib/<t>/tcp.npy            TCP pose at calibration time (6 values)
    RH20T_cfg<N>/task_<a>_user_<b>_scene_<c>_cfg_000<N>/
        metadata.json                         {"calib": <t>, ...}
        cam_<serial>/color.mp4                the camera's video (640x360)
        cam_<serial>/timestamps.npy           {"color": [ms, ...], ...}: one timestamp per video frame
        transformed/joint.npy                 {serial: {ms: joint angles}} (cfg5: 7 angles + 7 velocities)
        transformed/gripper.npy               {serial: {ms: {"gripper_info": [width_mm, ...], ...}}}

The per-configuration constants come from ``rh20t_api/configs/configs.json``
(:data:`CONFIGS`): the in-hand camera used to place the base
(``in_hand[0]``), ``tc_mat`` and ``align_mat_base``; the calibration TCP is
preprocessed as ``rh20t_api/configurations.py`` does (Franka: rotation
vector, then a flip about x; KUKA: millimetres → metres, static-xyz Euler
angles) and turned into a quaternion. The base-aligned extrinsic is then
:func:`oscar_embodiments.franka.adapters.rh20t_base_to_camera` (or the kuka
one), the trajectory :func:`~oscar_embodiments.franka.adapters.from_rh20t` /
:func:`oscar_embodiments.kuka.adapters.from_rh20t`.

All ``.npy`` dicts are pickles; they are read by
:func:`oscar_core.data.readers._npy.load_npy`, which refuses every global but
numpy's reconstructors. Camera: an external (static) camera, the first
serial (sorted) that is not an in-hand camera; ``ref.meta["camera"]`` may
name another. Intrinsics are scaled from 1280x720 to the video's size.
Human-demonstration folders (``..._human``) are skipped.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ...plugin.reader import Episode, EpisodeError, EpisodeRef, Reader
from ._common import episode_errors, local_root, probe_video, read_json, video_header
from ._npy import NpyPickleError, load_npy

__all__ = ["RH20TReader", "CONFIGS", "calib_tcp_quaternion"]

#: cfg number → (embodiment, in-hand serial placing the base, tc_mat, align_mat_base), from configs.json
CONFIGS: dict[int, tuple[str, str, list, list]] = {
    5: (
        "franka",
        "104422070042",
        [[0, 1, 0, 0.033], [-1, 0, 0, -0.05], [0, 0, 1, 0.09], [0, 0, 0, 1]],
        np.eye(4).tolist(),
    ),
    7: (
        "kuka",
        "135122075425",
        [[0, -1, 0, 0.035], [1, 0, 0, 0.055], [0, 0, 1, 0.20], [0, 0, 0, 1]],
        np.eye(4).tolist(),
    ),
}
#: every in-hand serial configs.json lists for the configuration (not offered as cameras)
IN_HAND = {5: ("104422070042", "135122079702", "104422071090"), 7: ("135122075425", "135122070361", "104422071090")}
CALIB_SIZE = (1280, 720)
_SCENE = re.compile(r"^task_\d+_user_\d+_scene_\d+_cfg_(\d+)$")


def calib_tcp_quaternion(tcp: Any, cfg: int) -> np.ndarray:
    """RH20T's calibration TCP (``calib/<t>/tcp.npy``, 6 values) → ``[x, y, z, qw, qx, qy, qz]`` (metres).

    cfg 5 (Franka): ``[x, y, z, rotation vector]``, rotated by diag(1, -1, -1)
    (``franka_tcp_preprocessor``); cfg 7 (KUKA): ``[x, y, z]`` in mm and
    static-xyz Euler angles in rad (``kuka_tcp_preprocessor``, ``tcp_as_q``).
    """
    from scipy.spatial.transform import Rotation

    p = np.asarray(tcp, dtype=np.float64).reshape(-1)
    if p.shape == (7,):
        return p
    if p.shape != (6,):
        raise ValueError(f"expected 6 (or 7) values, found shape {p.shape}")
    if cfg == 5:
        R = Rotation.from_rotvec(p[3:]).as_matrix() @ np.diag([1.0, -1.0, -1.0])
        t = p[:3]
    else:
        R = Rotation.from_euler("xyz", p[3:]).as_matrix()
        t = p[:3] / 1000.0
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([*t, w, x, y, z])


def _npy(path: Path, eid: str):
    try:
        return load_npy(path)
    except NpyPickleError as e:
        raise EpisodeError(eid, e.path, e.field, e.expected, e.found) from None


class RH20TReader(Reader):
    """RH20T cfg5 / cfg7 scenes → franka / kuka trajectories seen by a static camera."""

    name = "rh20t"
    description = "RH20T cfg5 (Franka) / cfg7 (KUKA): transformed/*.npy + calib + cam_<serial>/color.mp4"
    embodiments = ("franka", "kuka")

    def list_episodes(self, source: str) -> Iterator[EpisodeRef]:
        root = local_root(source, self.name)
        scenes = [p for p in sorted(root.glob("*")) + sorted(root.glob("*/*")) if p.is_dir() and _SCENE.match(p.name)]
        for scene in scenes:
            cfg = int(_SCENE.match(scene.name).group(1))
            if cfg not in CONFIGS:
                continue
            emb = CONFIGS[cfg][0]
            serials = sorted(p.name[4:] for p in scene.glob("cam_*") if p.is_dir())
            cams = tuple(s for s in serials if s not in IN_HAND[cfg])
            src = f"rh20t_cfg{cfg}"
            task = scene.name.split("_user_")[0]
            yield EpisodeRef(
                f"{src}/{scene.name}",
                src,
                self.name,
                emb,
                {
                    "scene": str(scene),
                    "states": str(scene / "transformed" / "joint.npy"),
                    "calibration": str(scene.parent / "calib"),
                    "video": str(scene / f"cam_{cams[0]}" / "color.mp4") if cams else "",
                },
                n_frames=None,
                fps=None,
                task=None,
                cameras=cams,
                meta={"cfg": cfg, "camera": cams[0] if cams else None, "task_id": task},
            )

    def load_episode(self, ref: EpisodeRef, registry=None) -> Episode:
        eid, scene, cfg = ref.episode_id, Path(ref.paths["scene"]), int(ref.meta["cfg"])
        emb, in_hand, tc_mat, align = CONFIGS[cfg]
        if emb == "franka":
            from oscar_embodiments.franka.adapters import from_rh20t, rh20t_base_to_camera
        else:
            from oscar_embodiments.kuka.adapters import from_rh20t, rh20t_base_to_camera
        serial = ref.meta.get("camera")
        if not serial:
            raise EpisodeError(eid, scene, "cam_<serial>", "a static (not in-hand) camera folder", "none")
        meta = read_json(scene / "metadata.json", eid, "the scene metadata")
        calib_t = meta.get("calib") if isinstance(meta, dict) else None
        if calib_t in (None, -1):
            raise EpisodeError(
                eid, scene / "metadata.json", "calib", "the timestamp of the scene's calibration", repr(calib_t)
            )
        calib = Path(ref.paths["calibration"]) / str(calib_t)
        intrinsics = _npy(calib / "intrinsics.npy", eid)
        extrinsics = _npy(calib / "extrinsics.npy", eid)
        tcp = _npy(calib / "tcp.npy", eid)
        joint = _npy(scene / "transformed" / "joint.npy", eid)
        gripper = _npy(scene / "transformed" / "gripper.npy", eid)
        for name, d in (
            ("intrinsics.npy", intrinsics),
            ("extrinsics.npy", extrinsics),
            ("joint.npy", joint),
            ("gripper.npy", gripper),
        ):
            if not isinstance(d, dict):
                raise EpisodeError(eid, name, "<file>", "a pickled dict keyed by camera serial", type(d).__name__)
        try:
            calib_tcp = calib_tcp_quaternion(tcp, cfg)
        except ValueError as e:
            raise EpisodeError(eid, calib / "tcp.npy", "<file>", "the calibration TCP (6 values)", str(e)) from None
        with episode_errors(eid, calib / "extrinsics.npy"):
            E = rh20t_base_to_camera(
                extrinsics, serial, in_hand, tc_mat, calib_tcp, align, source=str(calib / "extrinsics.npy")
            )
        with episode_errors(eid, scene / "transformed" / "joint.npy"):
            traj, camera = from_rh20t(
                joint,
                gripper,
                intrinsics,
                {serial: E},
                serial,
                image_size=CALIB_SIZE,
                source=str(scene / "transformed"),
            )
        cam_dir = scene / f"cam_{serial}"
        mp4 = cam_dir / "color.mp4"
        rate, width, height = video_header(eid, mp4, serial, self.name)
        stamps = _npy(cam_dir / "timestamps.npy", eid)
        color = stamps.get("color") if isinstance(stamps, dict) else None
        if color is None:
            raise EpisodeError(
                eid, cam_dir / "timestamps.npy", "color", "one timestamp (ms) per video frame", "missing"
            )
        color = [int(c) for c in color]
        ts = sorted(int(k) for k in joint[serial])  # the trajectory's frames (from_rh20t sorts them the same way)
        if ts[0] not in color or color[color.index(ts[0]) : color.index(ts[0]) + len(ts)] != ts:
            raise EpisodeError(
                eid,
                cam_dir / "timestamps.npy",
                "color",
                f"the {len(ts)} joint timestamps of camera {serial} as consecutive video frames",
                f"{len(color)} video timestamps that do not contain them in order",
            )
        video = probe_video(
            eid, mp4, len(ts), rate, start=color.index(ts[0]) / (rate or 10.0), field=serial, reader=self.name
        )
        if (width, height) != CALIB_SIZE:
            camera = camera.resized(width, height)
        return Episode(ref, traj, camera, serial, video, ref.task)
