"""Distil the toy VAE's full encoder into a tiny condition encoder (:mod:`oscar_core.model.tiny_encoder`, TAEHV).

What it will encode is the closed loop's condition: each chunk's skeleton video. So the data are the toy clips'
condition videos (each clip's stored ``skeleton`` video, drawn by the same renderer the closed loop draws its
conditions with), in windows of the model's chunk length (17 frames for ``oscar-toy``), one window per clip at a
start drawn with the seed. Target: the *full encoder's* normalised latents of the same window (what the DiT was
trained on and sees in a rollout), computed once before training. Loss: mean squared error of the tiny encoder's
normalised latents against them (the normalisation is the VAE's ``latents_mean`` / ``latents_std``, so every
channel weighs by its spread, as the DiT sees it).

Held out: the clips whose ``meta.episode % heldout_every == heldout_residue`` (as ``train-tiny-decoder`` holds them
out); their first window gives the held-out relative RMS error, sqrt(sum (tiny − full)²) / sqrt(sum full²) over all
latent values. AdamW, cosine decay to 5 %; seeded; one thread by default.

Output folder::

    OUT/tiny_encoder.safetensors     encoder.* tensors; the architecture in the file's metadata (load_tiny_encoder)
    OUT/tiny_encoder_card.json       settings, loss curve, held-out relative RMS, wall and CPU seconds
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .._util.atomic import atomic_write_bytes
from .._util.log import get_logger, progress_bar

__all__ = [
    "TinyEncoderTrainConfig",
    "TOY_TINY_ENCODER",
    "train_tiny_encoder",
    "condition_windows",
    "full_encode",
    "relative_rms",
]

_log = get_logger(__name__)

#: The toy tiny encoder's shape: the toy VAE's 16 latent channels, /4 in space (two halvings, not WAN's three; the
#: last stage keeps 16 x 16), /4 in time; 16 channels (TAEHV's are 64): 24 CPU ms per 17-frame 64 x 64 window against
#: 92 for the toy's full encoder (one thread, measured 2026-11-29), 94 k parameters, 0.38 MB in float32.
TOY_TINY_ENCODER = dict(
    latent_channels=16, space_downscale=(True, True, False), time_downscale=(True, True, False), width=16
)


@dataclass
class TinyEncoderTrainConfig:
    """Settings of ``oscar toyworld train-tiny-encoder`` (every field is a CLI flag of the same name)."""

    steps: int = 200  # optimiser steps
    batch: int = 4  # condition windows per step
    lr: float = 2e-3  # AdamW learning rate, cosine-decayed to 5 % over the run
    window: int = 17  # frames per window (4k + 1): oscar-toy's chunk_frames
    train_windows: int = 480  # training windows (one per clip, drawn with the seed), encoded once by the full VAE
    eval_windows: int = 48  # held-out windows for the relative RMS
    heldout_every: int = 10  # a clip is held out when meta.episode % heldout_every == heldout_residue
    heldout_residue: int = 8  # (generate's own held-out episodes end in 9 and are not in a train-split cache)
    seed: int = 0
    threads: int = 1  # torch.set_num_threads
    eval_every: int = 500  # held-out relative RMS every N steps (0: only at the end)


def condition_windows(
    clipsets, window: int, heldout_every: int, heldout_residue: int, rng: np.random.Generator
) -> tuple[list[tuple[str, np.ndarray]], list[tuple[str, np.ndarray]]]:
    """``(train, heldout)`` lists of ``(clip id, (window, H, W, 3) uint8)``: one window of each clip's stored
    condition video (its ``skeleton`` file), at a start drawn from ``rng`` for a training clip and at frame 0 for a
    held-out one, split by episode. ValueError naming the clip set on a clip without a condition video or too short."""
    from ..media.video import read_video
    from ..train.clips import ClipSet

    train, held = [], []
    for root in clipsets:
        cs = ClipSet(root)
        for rec in cs:
            if "skeleton" not in rec.files:
                raise ValueError(f"{cs.root}: expected clips with a skeleton video, clip {rec.id} has none")
            video = read_video(cs.path(rec, "skeleton"))
            if len(video) < window:
                raise ValueError(f"{cs.root}: clip {rec.id}: expected at least {window} frames, found {len(video)}")
            is_held = int(rec.meta.get("episode", 0)) % heldout_every == heldout_residue
            start = 0 if is_held else int(rng.integers(0, len(video) - window + 1))
            (held if is_held else train).append((rec.id, np.ascontiguousarray(video[start : start + window])))
    if not train or not held:
        raise ValueError(f"{list(map(str, clipsets))}: expected clips in both splits, found {len(train)} / {len(held)}")
    return train, held


def full_encode(vae, windows: np.ndarray, batch: int = 4) -> np.ndarray:
    """(N, z, T', h, w) float32 normalised latents of the full encoder of ``vae`` (a VideoVAE) for (N, T, H, W, 3)
    uint8 windows."""
    out = [vae.encode(vae.to_pixels(windows[i : i + batch])).numpy() for i in range(0, len(windows), batch)]
    return np.concatenate(out)


def relative_rms(pred: np.ndarray, target: np.ndarray) -> float:
    """sqrt(sum (pred − target)²) / sqrt(sum target²) over every value (0: equal; 1: as far as predicting zeros)."""
    pred, target = np.asarray(pred, np.float64), np.asarray(target, np.float64)
    return float(np.sqrt(np.sum((pred - target) ** 2) / np.sum(target**2)))


def train_tiny_encoder(
    clipsets, vae_folder, out, cfg: TinyEncoderTrainConfig, log: Callable[[str], None] | None = None
):
    """Encode the chosen windows with the full encoder, train, evaluate and save; returns the card (also written to
    ``OUT/tiny_encoder_card.json``). clipsets: clip-set folders whose clips hold a skeleton video; vae_folder: the
    ``vae/`` folder (``AutoencoderKLWan``) to distil."""
    import torch

    from ..model.chunks import check_frame_count
    from ..model.tiny_encoder import TinyEncoderNet, TinyVideoEncoder
    from ..model.vae import VideoVAE, load_vae_folder

    log = log or _log.info
    check_frame_count(cfg.window, 4, "--window")
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    t0, c0 = time.perf_counter(), time.process_time()
    vae = VideoVAE(load_vae_folder(vae_folder))
    train_all, held_all = condition_windows(clipsets, cfg.window, cfg.heldout_every, cfg.heldout_residue, rng)
    pick = rng.permutation(len(train_all))[: cfg.train_windows]
    train_x = np.stack([train_all[i][1] for i in pick])
    held = held_all[:: max(1, len(held_all) // cfg.eval_windows)][: cfg.eval_windows]  # spread over the clips
    held_x = np.stack([frames for _, frames in held])
    log(
        f"data: {len(train_all)} train clips, {len(held_all)} held out; encoding {len(train_x)} + {len(held_x)} windows"
    )
    train_z, held_z = full_encode(vae, train_x), full_encode(vae, held_x)
    teacher_s = (time.perf_counter() - t0, time.process_time() - c0)
    log(f"full encodes: {teacher_s[0]:.0f} s wall, {teacher_s[1]:.0f} s CPU")

    net = TinyEncoderNet(**TOY_TINY_ENCODER)
    n_params = sum(p.numel() for p in net.parameters())
    tiny = TinyVideoEncoder(net, vae.mean, vae.std)
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=0.0)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda s: 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(s / max(cfg.steps, 1), 1.0)))
    )
    mean, std = vae.mean.permute(0, 2, 1, 3, 4), vae.std.permute(0, 2, 1, 3, 4)  # (1, 1, z, 1, 1): the net's layout
    curve, evals = [], []

    def held_out_eval(step: int) -> dict:
        net.eval()
        pred = np.concatenate([tiny.encode(vae.to_pixels(held_x[i : i + 8])).numpy() for i in range(0, len(held_x), 8)])
        net.train()
        evals.append(
            {"step": step, "relative_rms": relative_rms(pred, held_z), "wall_s": round(time.perf_counter() - t0, 1)}
        )
        return evals[-1]

    log(f"model: TinyEncoderNet {TOY_TINY_ENCODER}, {n_params / 1e6:.3f} M parameters")
    net.train()
    t_train = time.perf_counter()
    bar = progress_bar(total=cfg.steps, desc="toyworld train-tiny-encoder", unit="step")
    for step in range(1, cfg.steps + 1):
        idx = rng.integers(0, len(train_x), cfg.batch)
        x = torch.from_numpy(train_x[idx]).permute(0, 1, 4, 2, 3).float().div(255.0)  # (B, T, 3, H, W) in [0, 1]
        target = torch.from_numpy(train_z[idx]).permute(0, 2, 1, 3, 4)  # (B, T', z, h, w) normalised
        loss = _train_step(net, opt, sched, x, target, mean, std)
        bar.update(1)
        if step % 25 == 0 or step == 1:
            wall = time.perf_counter() - t0
            curve.append({"step": step, "mse": float(loss.detach()), "wall_s": round(wall, 1)})
            bar.set_postfix(mse=f"{curve[-1]['mse']:.5f}", refresh=False)
            log(f"step {step}/{cfg.steps}  mse {curve[-1]['mse']:.5f}  {wall:.0f} s")
        if cfg.eval_every and step % cfg.eval_every == 0 and step < cfg.steps:
            log(
                f"step {step}: held-out relative RMS against the full encoder {held_out_eval(step)['relative_rms']:.4f}"
            )
    bar.close()
    net.eval()
    final = held_out_eval(cfg.steps)
    card = {
        "format": "oscar-tiny-encoder-card",
        "config": asdict(cfg),
        "architecture": {k: list(v) if isinstance(v, tuple) else v for k, v in TOY_TINY_ENCODER.items()},
        "parameters": n_params,
        "clipsets": [str(Path(c).resolve()) for c in clipsets],
        "vae": str(Path(vae_folder).resolve()),
        "data": "each clip's stored skeleton video, one window per clip",
        "target": "the full encoder's normalised latents of the same windows",
        "train_windows": len(train_x),
        "heldout_windows": len(held_x),
        "heldout_clips": [clip_id for clip_id, _ in held],
        "heldout_relative_rms": final["relative_rms"],
        "evals": evals,
        "curve": curve,
        "full_encode_s": {"wall": round(teacher_s[0], 1), "cpu": round(teacher_s[1], 1)},
        "train_wall_s": round(time.perf_counter() - t_train, 1),
        "wall_s": round(time.perf_counter() - t0, 1),
        "cpu_s": round(time.process_time() - c0, 1),
    }
    log(f"done: held-out relative RMS {final['relative_rms']:.4f} against the full encoder, {card['wall_s']:.0f} s")
    _save(net, Path(out), card)
    return card


def _train_step(net, opt, sched, x, target, mean, std):
    """One AdamW step (gradients clipped at 1, then the schedule's step) on the mean squared error between the net's
    latents for x (B, T, 3, H, W) in [0, 1], normalised by mean and std (1, 1, z, 1, 1), and target (B, T', z, h, w),
    the full encoder's normalised latents. Returns the loss, a 0-d tensor."""
    import torch

    pred = (net(x) - mean) / std
    loss = ((pred - target) ** 2).mean()
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
    opt.step()
    sched.step()
    return loss


def _save(net, out: Path, card: dict) -> None:
    from ..model.tiny_encoder import save_tiny_encoder

    save_tiny_encoder(net, out / "tiny_encoder.safetensors")
    atomic_write_bytes(out / "tiny_encoder_card.json", (json.dumps(card, indent=1) + "\n").encode())
