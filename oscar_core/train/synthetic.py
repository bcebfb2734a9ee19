"""A small synthetic clip set from the toy arm, for tests, benchmarks and the docs' first run.

Each clip is a slice of the toy arm's bundled 81-frame reach–grasp–lift
(played forwards or backwards, from a different start), its RGB video the
skeleton drawn over a plain background with a little seeded noise — so the
skeleton really predicts the video and a tiny model has something to learn.
Nothing is downloaded; the toy arm plugin (examples/oscar-toyarm) must be
installed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .clips import Clip, ClipRecord, ClipSetWriter, clip_openness

__all__ = ["write_toy_clipset"]


def write_toy_clipset(
    root,
    clips: int = 4,
    frames: int = 33,
    width: int = 64,
    height: int = 48,
    sources: tuple[str, ...] = ("toy_a", "toy_b"),
    per_shard: int = 2,
    seed: int = 0,
    stored_skeleton: bool = False,
    prompt_dim: int | None = None,
    latents_vae=None,
    latents_window: int | None = None,
) -> Path:
    """Write ``clips`` clips of ``frames`` frames at ``width`` x ``height`` into clip set ``root``.

    Clip i has source ``sources[i % len(sources)]`` and id ``toy-<i>``.
    stored_skeleton: also store the skeleton video; prompt_dim: store a seeded
    (3, prompt_dim) prompt embedding; latents_vae (a ``VideoVAE``) with
    ``latents_window``: store cached latents of every window start —
    ``latents_vae="random"`` stores seeded N(0, 1) latents of the right shape
    instead (16 channels; fast, for tests of the loop that need no VAE).
    """
    from ..camera import load_camera
    from ..kinematics.trajectory import load_trajectory
    from ..plugin.registry import Registry
    from ..render.skeleton_video import render_skeleton_video

    emb = Registry().get("toyarm")
    full = load_trajectory(emb.example_trajectory)
    camera = load_camera(emb.example_camera)
    if frames > len(full):
        raise ValueError(f"frames: expected at most {len(full)} (the toy arm's example), found {frames}")
    rng = np.random.default_rng(seed)
    writer = ClipSetWriter(root)
    n_shards = (clips + per_shard - 1) // per_shard
    for s in range(n_shards):
        with writer.shard(f"shard-{s:06d}") as shard:
            for i in range(s * per_shard, min(clips, (s + 1) * per_shard)):
                start = (i * 7) % (len(full) - frames + 1)
                traj = full.time_slice(start, start + frames)
                if i % 2:
                    traj = traj.replace(q=traj.q[::-1].copy(), gripper=traj.gripper[::-1].copy())
                skel = render_skeleton_video(emb, traj, camera, (width, height))
                bg = np.full_like(skel, 60)
                bg[..., 2] = 90 + 10 * (i % 3)
                rgb = np.where(skel.any(-1, keepdims=True), skel, bg)
                rgb = np.clip(rgb.astype(np.int16) + rng.integers(-4, 5, rgb.shape), 0, 255).astype(np.uint8)
                op = clip_openness(emb, traj)
                rec = ClipRecord(
                    id=f"toy-{i}",
                    source=sources[i % len(sources)],
                    embodiment="toyarm",
                    n_frames=frames,
                    fps=float(traj.fps),
                    width=width,
                    height=height,
                    openness=tuple(map(tuple, op)),
                    files={},
                    caption="the toy arm picks up a cube",
                )
                extra = {}
                if stored_skeleton:
                    extra["skeleton"] = skel
                if prompt_dim:
                    extra["prompt_embeds"] = _prompt(prompt_dim, i)
                if isinstance(latents_vae, str) and latents_vae == "random":
                    extra["latents"] = _random_latents(i, frames, width, height, latents_window or frames)
                elif latents_vae is not None:
                    extra["latents"] = _latents(latents_vae, rgb, skel, latents_window or frames)
                shard.add(Clip(rec, rgb=rgb, trajectory=traj, camera=camera, **extra))
    return Path(root)


def _prompt(dim: int, i: int):
    import torch

    return torch.randn(3, dim, generator=torch.Generator().manual_seed(1000 + i))


def _latents(vae, rgb: np.ndarray, skel: np.ndarray, window: int) -> dict:
    import torch

    starts = list(range(0, len(rgb) - window + 1))
    video = torch.cat([vae.encode(vae.to_pixels(rgb[s : s + window])) for s in starts])
    skeleton = torch.cat([vae.encode(vae.to_pixels(skel[s : s + window])) for s in starts])
    return {"video": video, "skeleton": skeleton, "starts": starts, "window": window, "vae": "tiny"}


def _random_latents(i: int, frames: int, width: int, height: int, window: int) -> dict:
    import torch

    starts = list(range(0, frames - window + 1))
    g = torch.Generator().manual_seed(2000 + i)
    shape = (len(starts), 16, (window - 1) // 4 + 1, height // 8, width // 8)
    return {
        "video": torch.randn(shape, generator=g),
        "skeleton": torch.randn(shape, generator=g),
        "starts": starts,
        "window": window,
        "vae": "random",
    }
