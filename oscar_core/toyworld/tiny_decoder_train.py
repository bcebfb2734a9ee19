"""Distil the toy VAE's full decoder into a tiny decoder (:mod:`oscar_core.model.tiny_decoder`, the TAEHV design).

Input: the cached, normalised VAE latents of toy clips (``oscar train --cache-latents``: each clip's
``latents.safetensors`` holds ``video`` (windows, 16, T', h, w)); one window per clip, drawn with the seed. Target:
the *full decoder's* frames of those latents, decoded once before training and kept as uint8. Why the full
decode and not the true frames: the tiny decoder stands in for the full decoder, so the question it must answer is
"what would the full decoder have shown", and that is what its quality is measured against (PSNR and motion IoU
against the full decode, the judge's verdicts on both); the full decoder's own reconstruction error (about 25 dB
on held-out toy clips) is not something a decoder of the same latents can learn to undo, and fitting the true
frames would spend the tiny network's capacity on it. It also needs no video files: latents in, frames out.

Held out: the clips whose ``meta.episode % heldout_every == heldout_residue`` (every tenth episode, those ending
in 8, by default: ``oscar toyworld generate`` already keeps the episodes ending in 9 out of the train split, so a
cache of that split holds none of them);
their first window is used for the held-out PSNR. Loss: mean squared error in [-1, 1] pixels plus ``foreground``
× the squared error on pixels that move in the target window (:func:`~oscar_core.toyworld.vae_train.moving_pixels`),
the term that kept the arm and the ball in the toy VAE. AdamW, cosine decay to 5 %; seeded; one thread by default.

Output folder::

    OUT/tiny_decoder.safetensors     decoder.* tensors; the architecture in the file's metadata (load_tiny_decoder)
    OUT/tiny_decoder_card.json       settings, loss curve, held-out PSNR, wall and CPU seconds
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

__all__ = ["TinyDecoderTrainConfig", "TOY_TINY_DECODER", "train_tiny_decoder", "latent_windows", "full_decode"]

_log = get_logger(__name__)

#: The toy tiny decoder's shape: the toy VAE's 16 latent channels, x4 in space (two doublings, not WAN's three),
#: x4 in time; widths chosen for speed on a CPU: 64 CPU ms per 17-frame 64 x 64 chunk against 502 for the toy's
#: full decoder (one thread, measured 2026-11-29), 0.27 M parameters, 1.1 MB in float32.
TOY_TINY_DECODER = dict(
    latent_channels=16, space_upscale=(True, True, False), time_upscale=(False, True, True), widths=(32, 32, 16, 16)
)


@dataclass
class TinyDecoderTrainConfig:
    """Settings of ``oscar toyworld train-tiny-decoder`` (every field is a CLI flag of the same name)."""

    steps: int = 200  # optimiser steps
    batch: int = 2  # latent windows per step
    lr: float = 2e-3  # AdamW learning rate, cosine-decayed to 5 % over the run
    foreground: float = 10.0  # extra weight of the squared error on moving pixels (as the toy VAE's run B)
    train_windows: int = 160  # training windows (one per clip, drawn with the seed), decoded once by the full VAE
    eval_windows: int = 48  # held-out windows for the PSNR
    heldout_every: int = 10  # a clip is held out when meta.episode % heldout_every == heldout_residue
    heldout_residue: int = 8  # (generate's own held-out episodes end in 9 and are not in a train-split cache)
    seed: int = 0
    threads: int = 1  # torch.set_num_threads
    eval_every: int = 100  # held-out PSNR every N steps (0: only at the end)


def latent_windows(
    clipsets, heldout_every: int, heldout_residue: int
) -> tuple[list[tuple[str, np.ndarray]], list[tuple[str, np.ndarray]]]:
    """The latent windows of the cached clip sets, as ``(train, heldout)`` lists of ``(clip id, (W, z, T', h, w)
    float32)``: every window of each clip (its ``latents.safetensors`` ``video``), split by episode."""
    from safetensors.numpy import load_file

    from ..train.clips import ClipSet

    train, held = [], []
    for root in clipsets:
        cs = ClipSet(root)
        for rec in cs:
            if "latents" not in rec.files:
                raise ValueError(f"{cs.root}: expected a cached-latents clip set, clip {rec.id} has no latents file")
            video = load_file(str(cs.path(rec, "latents")))["video"]
            episode = int(rec.meta.get("episode", 0))
            (held if episode % heldout_every == heldout_residue else train).append((rec.id, video))
    if not train or not held:
        raise ValueError(f"{list(map(str, clipsets))}: expected clips in both splits, found {len(train)} / {len(held)}")
    return train, held


def full_decode(vae, latents: np.ndarray, batch: int = 4) -> np.ndarray:
    """(N, 3, T, H, W) uint8 frames of the full decoder of ``vae`` (a VideoVAE) for (N, z, T', h, w) latents."""
    import torch

    out = []
    for i in range(0, len(latents), batch):
        x = vae.decode(torch.from_numpy(np.ascontiguousarray(latents[i : i + batch])))
        out.append(((x.clamp(-1, 1) + 1.0) * 127.5).round().to(torch.uint8).numpy())
    return np.concatenate(out)


def _psnr_db(pred: np.ndarray, target: np.ndarray) -> float:
    """Mean over windows and frames of the per-frame PSNR (dB) of uint8 (N, 3, T, H, W) arrays."""
    from ..metrics import psnr

    scores = [
        psnr(a.transpose(1, 2, 3, 0), b.transpose(1, 2, 3, 0), n_frames=None).mean() for a, b in zip(pred, target)
    ]
    return float(np.mean(scores))


def _to_uint8(x) -> np.ndarray:
    import torch

    return ((x.detach().clamp(-1, 1) + 1.0) * 127.5).round().to(torch.uint8).numpy()


def train_tiny_decoder(
    clipsets, vae_folder, out, cfg: TinyDecoderTrainConfig, log: Callable[[str], None] | None = None
):
    """Decode the chosen windows with the full decoder, train, evaluate and save; returns the card (also written to
    ``OUT/tiny_decoder_card.json``). clipsets: cached-latents clip-set folders; vae_folder: the ``vae/`` folder
    (``AutoencoderKLWan``) whose latents they hold."""
    import torch

    from ..model.tiny_decoder import TinyDecoderNet, TinyVideoDecoder
    from ..model.vae import VideoVAE, load_vae_folder

    log = log or _log.info
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    t0, c0 = time.perf_counter(), time.process_time()
    vae = VideoVAE(load_vae_folder(vae_folder))
    train_all, held_all = latent_windows(clipsets, cfg.heldout_every, cfg.heldout_residue)
    pick = rng.permutation(len(train_all))[: cfg.train_windows]
    train_z = np.stack([train_all[i][1][rng.integers(len(train_all[i][1]))] for i in pick])
    held = held_all[:: max(1, len(held_all) // cfg.eval_windows)][: cfg.eval_windows]  # spread over the clips
    held_z = np.stack([windows[0] for _, windows in held])
    log(
        f"data: {len(train_all)} train clips, {len(held_all)} held out; decoding {len(train_z)} + {len(held_z)} windows"
    )
    train_y, held_y = full_decode(vae, train_z), full_decode(vae, held_z)
    teacher_s = (time.perf_counter() - t0, time.process_time() - c0)
    log(f"full decodes: {teacher_s[0]:.0f} s wall, {teacher_s[1]:.0f} s CPU")

    net = TinyDecoderNet(**TOY_TINY_DECODER)
    n_params = sum(p.numel() for p in net.parameters())
    tiny = TinyVideoDecoder(net, vae.mean, vae.std)
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=0.0)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda s: 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(s / max(cfg.steps, 1), 1.0)))
    )
    mean, std = vae.mean, vae.std
    curve, evals = [], []

    def held_out_eval(step: int) -> dict:
        net.eval()
        pred = np.concatenate(
            [_to_uint8(tiny.decode(torch.from_numpy(held_z[i : i + 8]))) for i in range(0, len(held_z), 8)]
        )
        net.train()
        evals.append({"step": step, "psnr_db": _psnr_db(pred, held_y), "wall_s": round(time.perf_counter() - t0, 1)})
        return evals[-1]

    from .vae_train import moving_pixels

    log(f"model: TinyDecoderNet {TOY_TINY_DECODER}, {n_params / 1e6:.2f} M parameters")
    net.train()
    t_train = time.perf_counter()
    bar = progress_bar(total=cfg.steps, desc="toyworld train-tiny-decoder", unit="step")
    for step in range(1, cfg.steps + 1):
        idx = rng.integers(0, len(train_z), cfg.batch)
        z = torch.from_numpy(train_z[idx]) * std + mean  # un-normalised latents, as the net takes them
        y = torch.from_numpy(train_y[idx]).float().div(127.5).sub(1.0)  # (B, 3, T, H, W) in [-1, 1]
        x = net(z.permute(0, 2, 1, 3, 4)).permute(0, 2, 1, 3, 4).mul(2.0).sub(1.0)
        err = (x - y) ** 2
        mse = err.mean()
        loss = mse + cfg.foreground * (moving_pixels(y) * err).mean() if cfg.foreground else mse
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
        opt.step()
        sched.step()
        bar.update(1)
        if step % 25 == 0 or step == 1:
            wall = time.perf_counter() - t0
            curve.append({"step": step, "mse": float(mse.detach()), "wall_s": round(wall, 1)})
            bar.set_postfix(mse=f"{curve[-1]['mse']:.5f}", refresh=False)
            log(f"step {step}/{cfg.steps}  mse {curve[-1]['mse']:.5f}  {wall:.0f} s")
        if cfg.eval_every and step % cfg.eval_every == 0 and step < cfg.steps:
            log(f"step {step}: held-out PSNR against the full decode {held_out_eval(step)['psnr_db']:.2f} dB")
    bar.close()
    net.eval()
    final = held_out_eval(cfg.steps)
    card = {
        "format": "oscar-tiny-decoder-card",
        "config": asdict(cfg),
        "architecture": {k: list(v) if isinstance(v, tuple) else v for k, v in TOY_TINY_DECODER.items()},
        "parameters": n_params,
        "clipsets": [str(Path(c).resolve()) for c in clipsets],
        "vae": str(Path(vae_folder).resolve()),
        "target": "the full decoder's frames of the same latents (uint8)",
        "train_windows": len(train_z),
        "heldout_windows": len(held_z),
        "heldout_clips": [clip_id for clip_id, _ in held],
        "heldout_psnr_db": final["psnr_db"],
        "evals": evals,
        "curve": curve,
        "full_decode_s": {"wall": round(teacher_s[0], 1), "cpu": round(teacher_s[1], 1)},
        "train_wall_s": round(time.perf_counter() - t_train, 1),
        "wall_s": round(time.perf_counter() - t0, 1),
        "cpu_s": round(time.process_time() - c0, 1),
    }
    log(f"done: held-out PSNR {final['psnr_db']:.2f} dB against the full decode, {card['wall_s']:.0f} s")
    _save(net, Path(out), card)
    return card


def _save(net, out: Path, card: dict) -> None:
    from ..model.tiny_decoder import save_tiny_decoder

    save_tiny_decoder(net, out / "tiny_decoder.safetensors")
    atomic_write_bytes(out / "tiny_decoder_card.json", (json.dumps(card, indent=1) + "\n").encode())
