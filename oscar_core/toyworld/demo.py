"""The toy world's part of ``make demo``: roll the bundled ``oscar-toy`` model out on a held-out episode.

The episode is regenerated from its seed (episode 9 of ``franka`` under seed
0: a held-out episode of the shipped model's training set, never trained
on), so the demo needs no data. It writes ``toyworld_rollout.mp4``: rollout |
ground truth | skeleton side by side, each panel scaled up ``scale`` times
(nearest neighbour: the pixels are the model's).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

__all__ = ["DEMO_EPISODE", "toy_rollout_demo", "side_by_side"]

#: (embodiment, seed, index) of the demo's held-out episode.
DEMO_EPISODE = ("franka", 0, 9)


def side_by_side(*videos: np.ndarray, scale: int = 2, gap: int = 2) -> np.ndarray:
    """(T, H·scale, n·W·scale + (n − 1)·gap, 3) uint8: the (T, H, W, 3) videos next to each other, scaled up."""
    T = min(len(v) for v in videos)
    panels = [np.repeat(np.repeat(v[:T], scale, axis=1), scale, axis=2) for v in videos]
    H = panels[0].shape[1]
    bar = np.full((T, H, gap, 3), 255, np.uint8)
    parts = []
    for i, p in enumerate(panels):
        parts += [bar, p] if i else [p]
    return np.concatenate(parts, axis=2)


def toy_rollout_demo(
    out_dir, model="oscar-toy", registry=None, steps: int | None = 20, guidance: float | None = 3.0, seed: int = 0
) -> tuple[np.ndarray, dict]:
    """Roll ``model`` out on :data:`DEMO_EPISODE`; returns the side-by-side video and a summary.

    Writes ``OUT_DIR/toyworld_rollout.mp4``. Sampler: 20 UniPC steps,
    guidance 3 (the settings of the toy table, docs/toyworld.md). The summary holds the path, the
    wall time of the rollout and its PSNR against the ground truth.
    """
    import torch

    import oscar_zoo

    from ..media.video import write_video
    from ..metrics import psnr
    from ..model.gripper_signal import gripper_input
    from ..plugin.registry import Registry
    from ..render.skeleton_video import render_skeleton_video
    from .episode import episode_rng, make_episode
    from .rollouts import sampler_for_card

    registry = registry or Registry()
    m = oscar_zoo.load(model) if isinstance(model, (str, Path)) else model
    name, ep_seed, index = DEMO_EPISODE
    emb = registry.get(name)
    w, h = m.card.width or 64, m.card.height or 64
    ep = make_episode(emb, episode_rng(ep_seed, name, index), w, h, m.card.chunk_frames)
    skel = render_skeleton_video(emb, ep.trajectory, ep.camera)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a 64x64 rollout is latency-bound: one thread is fastest on a shared CPU
    try:
        t0 = time.perf_counter()
        result = m.rollout(
            ep.rgb[0],
            skel,
            sampler=sampler_for_card(m.card, steps, guidance),
            seed=seed,
            progress=False,
            keep_chunks=False,
            **gripper_input(m.card, emb, ep.trajectory),
        )
        wall = time.perf_counter() - t0
    finally:
        torch.set_num_threads(threads)
    video = side_by_side(result.frames, ep.rgb, skel)
    out = write_video(Path(out_dir) / "toyworld_rollout.mp4", video, ep.trajectory.fps)
    score = float(np.mean(np.minimum(psnr(result.frames[1:], ep.rgb[1:], n_frames=None), 100.0)))
    return video, {
        "path": str(out),
        "episode": f"{name}-{index:06d} (seed {ep_seed})",
        "rollout_seconds": round(wall, 3),
        "psnr_db": round(score, 2),
        "model": m.card.name,
    }
