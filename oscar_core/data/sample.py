"""``oscar data sample-dataset OUT``: a small dataset in a real layout, so the data quick start runs offline.

The dataset is LeRobot v3.0 with DROID's columns (the ``lerobot`` reader's
``droid`` profile, embodiment ``franka_robotiq``): ``meta/info.json``,
``meta/episodes/chunk-000/file-000.parquet`` (one row per episode with its
time range in the shared video), ``data/chunk-000/file-000.parquet`` (the
frames of every episode: ``observation.state.joint_position``,
``observation.state.gripper_position``, ``camera_extrinsics.exterior_1_left``)
and one MP4 shared by all episodes,
``videos/observation.images.exterior_1_left/chunk-000/file-000.mp4``. DROID
on the Hub publishes no intrinsics; this dataset writes its camera's in
``meta/info.json`` (``features[<video key>]["info"]["camera.intrinsics"]``,
``[fx, fy, cx, cy]`` pixels of the stored video), where the reader finds them.
Each episode is the Franka example motion (``embodiments/franka``) shifted by
a seeded smooth offset, filmed from a static exterior camera: the robot's own
skeleton drawn over a still textured background.

Chosen so every stage has something to do (``EXPECTED``, by task text):

* ``normal-*``: kept;
* ``short``: 40 frames, rejected by ``filter:length`` (< 70);
* ``still``: the arm does not move, rejected by ``filter:action``;
* ``copy-of-0``: episode 0's motion again (a fraction of a millimetre off),
  rejected by ``dedup:duplicate`` with ``oscar data dedup --embedder
  trajectory`` (no weights to download).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._util.atomic import atomic_write_bytes
from .._util.optional import require

__all__ = ["write_sample_dataset", "EXPECTED", "VIDEO_KEY", "CAMERA"]

CAMERA = "exterior_1_left"
VIDEO_KEY = f"observation.images.{CAMERA}"
FPS = 15.0
#: task text → what the pipeline does with the episode
EXPECTED = {
    "normal-0": "kept",
    "normal-1": "kept",
    "normal-2": "kept",
    "normal-3": "kept",
    "short": "filter:length",
    "still": "filter:action",
    "copy-of-0": "dedup:duplicate",
}


def _motion(q0: np.ndarray, g0: np.ndarray, rng: np.random.Generator, n: int, still: bool = False):
    """(n, 7) joints and (n, 1) gripper: the example motion resampled to n frames plus a smooth random offset."""
    t = np.linspace(0.0, len(q0) - 1, n)
    q = np.stack([np.interp(t, np.arange(len(q0)), q0[:, j]) for j in range(q0.shape[1])], axis=1)
    g = np.interp(t, np.arange(len(g0)), g0[:, 0])[:, None]
    phase = rng.uniform(0, 2 * np.pi, 7)
    q = q + 0.5 * np.sin(np.linspace(0, np.pi, n)[:, None] + phase) * rng.uniform(-1, 1, 7)
    if still:
        q, g = np.repeat(q[:1], n, axis=0), np.repeat(g[:1], n, axis=0)
    return q, g


def _texture(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    import cv2

    img = cv2.GaussianBlur(rng.random((h, w, 3)).astype(np.float32), (0, 0), 3.0)
    img = (img - img.min()) / (img.max() - img.min() + 1e-9)
    return (40 + 150 * img).astype(np.uint8)


def _episode_plan(example, frames: int, seed: int) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """``(task, q, gripper)`` per episode, in :data:`EXPECTED`'s order: q (T, 7) radians, gripper (T, 1) in [0, 1],
    drawn from the example motion ``example`` (``q``, ``gripper``) and deterministic in ``seed``."""
    rng = np.random.default_rng(seed)
    plan = []
    base = [_motion(example["q"], example["gripper"], np.random.default_rng([seed, e]), frames) for e in range(4)]
    plan += [(f"normal-{e}", *base[e]) for e in range(4)]
    plan.append(("short", *_motion(example["q"], example["gripper"], np.random.default_rng([seed, 10]), 40)))
    plan.append(
        ("still", *_motion(example["q"], example["gripper"], np.random.default_rng([seed, 11]), frames, still=True))
    )
    plan.append(("copy-of-0", base[0][0] + 0.0005 * rng.standard_normal(base[0][0].shape), base[0][1]))
    return plan


def _camera_fields(cam0, size: tuple[int, int]) -> tuple[list[float], list[float]]:
    """``(intrinsics, extrinsic)`` of the example camera cropped to ``size`` (width, height) pixels:
    ``[fx, fy, cx, cy]`` pixels and DROID's ``[x, y, z, rx, ry, rz]`` (metres, xyz Euler radians)."""
    from scipy.spatial.transform import Rotation

    w, h = size
    k = cam0.resized(w, h, mode="crop").intrinsics
    intrinsics = [float(k.fx), float(k.fy), float(k.cx), float(k.cy)]
    pose = np.asarray(cam0.camera_to_world if hasattr(cam0, "camera_to_world") else cam0.extrinsic, dtype=float)
    extrinsic = list(pose[:3, 3]) + list(Rotation.from_matrix(pose[:3, :3]).as_euler("xyz"))
    return intrinsics, extrinsic


def _info_json(plan, intrinsics: list[float], size: tuple[int, int]) -> dict:
    """``meta/info.json`` of the dataset: LeRobot v3.0 with DROID's feature names, the camera's intrinsics in the
    video feature's ``info``."""
    w, h = size
    feat = lambda shape, dtype="float32": {"dtype": dtype, "shape": shape, "names": None}  # noqa: E731
    return {
        "codebase_version": "v3.0",
        "robot_type": "franka",
        "fps": FPS,
        "chunks_size": 1000,
        "total_episodes": len(plan),
        "total_frames": int(sum(len(q) for _, q, _ in plan)),
        "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
        "features": {
            "observation.state.joint_position": feat([7]),
            "observation.state.gripper_position": feat([1]),
            f"camera_extrinsics.{CAMERA}": feat([6], "float64"),
            "timestamp": feat([1]),
            "frame_index": feat([1], "int64"),
            "episode_index": feat([1], "int64"),
            "index": feat([1], "int64"),
            VIDEO_KEY: {
                "dtype": "video",
                "shape": [h, w, 3],
                "names": ["height", "width", "channels"],
                "info": {
                    "video.fps": FPS,
                    "video.codec": "h264",
                    "video.pix_fmt": "yuv420p",
                    "camera.intrinsics": intrinsics,
                },
            },
        },
    }


def _episode_rows(plan, emb, intrinsics, extrinsic, size: tuple[int, int], seed: int):
    """Draws every episode of ``plan`` and lays out its rows. Returns ``(columns, episodes, frames)``: the frame
    table's columns (name → list, one entry per frame of all episodes), one dict per episode for
    ``meta/episodes`` and the shared video's (N, H, W, 3) uint8 frames."""
    from oscar_embodiments.franka.adapters import from_droid

    from ..render.skeleton_video import render_skeleton_video

    w, h = size
    cols: dict[str, list] = {
        k: []
        for k in (
            "observation.state.joint_position",
            "observation.state.gripper_position",
            f"camera_extrinsics.{CAMERA}",
            "timestamp",
            "frame_index",
            "episode_index",
            "index",
        )
    }
    episodes, video, start, t0 = [], [], 0, 0.0
    for e, (task, q, g) in enumerate(plan):
        T = len(q)
        record = {"observation/joint_position": q, "observation/gripper_position": g}
        traj, camera = from_droid(
            record,
            CAMERA,
            extrinsic=extrinsic,
            intrinsics=intrinsics,
            image_size=(w, h),
            fps=FPS,
            source=f"sample {task}",
        )
        skel = render_skeleton_video(emb, traj, camera, (w, h))
        bg = _texture(np.random.default_rng([seed, 100 + e]), h, w)
        video.append(np.where(skel.max(axis=-1, keepdims=True) > 0, skel, bg[None]))
        cols["observation.state.joint_position"] += q.astype(np.float32).tolist()
        cols["observation.state.gripper_position"] += g.astype(np.float32).tolist()
        cols[f"camera_extrinsics.{CAMERA}"] += [extrinsic] * T
        cols["timestamp"] += (np.arange(T) / FPS).tolist()
        cols["frame_index"] += list(range(T))
        cols["episode_index"] += [e] * T
        cols["index"] += list(range(start, start + T))
        episodes.append(
            {
                "episode_index": e,
                "tasks": [task],
                "length": T,
                "data/chunk_index": 0,
                "data/file_index": 0,
                "dataset_from_index": start,
                "dataset_to_index": start + T,
                f"videos/{VIDEO_KEY}/chunk_index": 0,
                f"videos/{VIDEO_KEY}/file_index": 0,
                f"videos/{VIDEO_KEY}/from_timestamp": t0,
                f"videos/{VIDEO_KEY}/to_timestamp": t0 + T / FPS,
            }
        )
        start, t0 = start + T, t0 + T / FPS
    return cols, episodes, np.concatenate(video)


def _write_dataset(out: Path, cols: dict, episodes: list[dict], video: np.ndarray, info: dict) -> None:
    """Writes the two parquet tables, the shared MP4 and ``meta/info.json`` (the last) under ``out``."""
    import io

    pa = require("pyarrow", "data")
    import pyarrow.parquet as pq

    from ..media.video import write_video

    for table, path in (
        (pa.table(cols), out / "data" / "chunk-000" / "file-000.parquet"),
        (pa.Table.from_pylist(episodes), out / "meta" / "episodes" / "chunk-000" / "file-000.parquet"),
    ):
        path.parent.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        pq.write_table(table, buf)
        atomic_write_bytes(path, buf.getvalue())
    vdir = out / "videos" / VIDEO_KEY / "chunk-000"
    vdir.mkdir(parents=True, exist_ok=True)
    write_video(vdir / "file-000.mp4", video, FPS)
    atomic_write_bytes(out / "meta" / "info.json", (json.dumps(info, indent=2) + "\n").encode())


def write_sample_dataset(
    out, *, frames: int = 80, size: tuple[int, int] = (192, 108), seed: int = 0, registry=None
) -> dict:
    """Write the dataset of the module docstring to ``out`` (a new or empty folder); returns a summary
    (``expected``: episode id → ``kept`` or the rejection column the pipeline gives it).

    frames: length of the normal episodes (≥ 70, the length filter's default);
    size: video (width, height), 16:9 like the example camera. Deterministic in ``seed``.
    """
    require("pyarrow", "data")  # before anything is written
    from .. import load_camera
    from ..plugin.registry import Registry

    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise ValueError(f"{out}: expected a new or empty folder for the sample dataset, found files in it")
    reg = registry if registry is not None else Registry()
    emb = reg.get("franka_robotiq")
    assets = Path(__import__("oscar_embodiments.franka", fromlist=["x"]).__file__).parent / "assets"
    example = np.load(assets / "example_trajectory_robotiq.npz")
    intrinsics, extrinsic = _camera_fields(load_camera(assets / "example_camera_robotiq.json"), size)
    plan = _episode_plan(example, frames, seed)
    info = _info_json(plan, intrinsics, size)
    cols, episodes, video = _episode_rows(plan, emb, intrinsics, extrinsic, size, seed)
    _write_dataset(out, cols, episodes, video, info)
    return {
        "dataset": str(out),
        "reader": "lerobot",
        "episodes": len(plan),
        "frames": info["total_frames"],
        "expected": {f"droid/{e}": EXPECTED[task] for e, (task, _, _) in enumerate(plan)},
    }
