"""Builders of small synthetic datasets in the generic npz layout, for the data-pipeline tests and benchmark.

An episode is the toy arm's example trajectory rendered over a textured
background: the skeleton drawn by oscar's own renderer (so the projection the
filters measure is exactly where the arm is in the video), the background
shifted by ``pan`` pixels per frame to fake a moving camera.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ASSETS = REPO / "examples" / "oscar-toyarm" / "oscar_toyarm" / "assets"
if str(REPO / "examples" / "oscar-toyarm") not in sys.path:
    sys.path.insert(0, str(REPO / "examples" / "oscar-toyarm"))

SIZE = (128, 72)


def base_parts():
    from oscar_core import load_camera, load_trajectory

    return load_trajectory(ASSETS / "example_trajectory.npz"), load_camera(ASSETS / "example_camera.json")


def texture(seed: int, h: int, w: int) -> np.ndarray:
    """(h, w, 3) uint8 smooth random texture (blurred noise: optical flow can track it)."""
    import cv2

    rng = np.random.default_rng(seed)
    noise = rng.random((h, w, 3)).astype(np.float32)
    img = cv2.GaussianBlur(noise, (0, 0), 2.0)
    img = (img - img.min()) / (img.max() - img.min() + 1e-9)
    return (img * 255).astype(np.uint8)


def render_rgb(traj, cam, *, seed: int = 0, pan: float = 0.0, size=SIZE) -> np.ndarray:
    """(T, H, W, 3) uint8: skeleton over a texture; the texture moves ``pan`` pixels/frame to the left."""
    from oscar_core.render.skeleton_video import render_skeleton_video
    from oscar_toyarm import ToyArm

    W, H = size
    skel = render_skeleton_video(ToyArm(), traj, cam, (W, H))
    T = len(traj)
    margin = int(abs(pan) * T) + 2
    bg = texture(seed, H, W + margin)
    out = np.empty_like(skel)
    for t in range(T):
        x0 = int(round(pan * t)) if pan >= 0 else margin + int(round(pan * t)) - 2
        frame = bg[:, x0 : x0 + W]
        drawn = skel[t].max(axis=-1, keepdims=True) > 0
        out[t] = np.where(drawn, skel[t], frame)
    return out


def write_episode(
    root: Path,
    name: str,
    traj=None,
    cam=None,
    *,
    seed: int = 0,
    pan: float = 0.0,
    size=SIZE,
    task: str | None = "move the arm",
    source: str | None = None,
    rgb: np.ndarray | None = None,
    video: str = "rgb.mkv",
) -> Path:
    """Write one npz-layout episode folder ``root/name``; returns it."""
    from oscar_core import save_camera, save_trajectory
    from oscar_core.media.video import write_video

    t0, c0 = base_parts()
    traj = t0 if traj is None else traj
    cam = (c0 if cam is None else cam).resized(*size)
    folder = Path(root) / name
    folder.mkdir(parents=True, exist_ok=True)
    if rgb is None:
        rgb = render_rgb(traj, cam, seed=seed, pan=pan, size=size)
    write_video(folder / video, rgb, traj.fps)
    save_trajectory(traj, folder / "trajectory.npz")
    save_camera(cam, folder / "camera.json")
    meta = {"embodiment": "toyarm", "task": task}
    if source:
        meta["source"] = source
    (folder / "episode.json").write_text(json.dumps(meta))
    return folder
