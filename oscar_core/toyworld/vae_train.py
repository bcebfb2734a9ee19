"""Train a small Wan VAE (:class:`~oscar_core.model.wan_vae.WanVAE`, the class the world model uses; saved in
diffusers' ``AutoencoderKLWan`` layout) on toy-world frames.

Seeded and single-threaded by default. The data are 5-frame windows (1 + 4:
one latent frame for the first pixel frame, one for the next four, as the
causal VAE splits time) cut at random from the clip set's ``train`` clips;
PSNR is measured by encoding and decoding whole held-out clips
(``meta.split == "heldout"``) through :class:`~oscar_core.model.vae.VideoVAE`.

Loss: mean squared error of the reconstruction in [-1, 1] pixels + ``kl``
× the posterior's KL divergence to N(0, I) per latent element + ``chroma``
× the mean squared error of each pixel's chroma (RGB minus its mean over the
three channels) + ``foreground`` × the mean squared error on moving pixels
(:func:`moving_pixels`). The decoder sees the posterior's mean (a sample of
it with ``sample_posterior``); evaluation always uses the mean. Plain MSE
settles on the floor, which is most of every frame: grey, blurred
reconstructions in which the arm is faint and the yellow ball and magenta
marker, which the evaluation finds by hue, are lost. The moving-pixel term
is what brought the arm, the ball and then the scene's hues back
(docs/toyworld.md, "The VAE"). After training, ``latents_mean`` and
``latents_std`` of the config are set to the per-channel statistics of the
training latents (32 clips spread over the set), so the normalised latents the DiT sees are about
zero-mean, unit-variance.

Output folder::

    OUT/vae/config.json, OUT/vae/diffusion_pytorch_model.safetensors   (what OscarWorldModel loads as vae/)
    OUT/vae_card.json   the command's settings, loss curve, held-out PSNR, wall time
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .._util.atomic import atomic_write_bytes
from .._util.log import get_logger, progress_bar
from .vae_resume import finish_state, load_resume_state, restore, resume_state_files, weights_sha256, write_files

__all__ = [
    "VAETrainConfig",
    "TOY_VAE_CONFIG",
    "train_vae",
    "load_clip_frames",
    "vae_psnr",
    "load_toy_vae",
    "write_reconstructions",
    "chroma_ratio",
    "moving_pixels",
    "ball_pixels",
    "ball_kept",
]

#: The toy world's VAE: z = 16 channels, 4x time compression (as the real WAN 2.1 VAE) but 4x space, not 8x:
#: two spatial levels instead of three, so a 64 x 64 frame keeps a 16 x 16 latent (at 8 x 8 the 3-pixel arm and
#: the 7-pixel ball blurred away: 18.4 dB after 45 min of training); base width 16.
TOY_VAE_CONFIG = dict(
    base_dim=16,
    z_dim=16,
    dim_mult=[1, 2, 2],
    num_res_blocks=1,
    attn_scales=[],
    temperal_downsample=[True, True],
    is_residual=False,
)


_log = get_logger(__name__)


@dataclass
class VAETrainConfig:
    """Settings of ``oscar toyworld train-vae`` (every field is a CLI flag of the same name)."""

    steps: int = 2000  # optimiser steps
    batch: int = 4  # windows per step
    window: int = 5  # frames per window (4k + 1)
    lr: float = 1e-3  # AdamW learning rate, cosine-decayed to 5 % over the run
    kl: float = 1e-4  # weight of the KL term (mean over latent elements)
    chroma: float = 0.0  # weight of an extra MSE on each pixel's chroma (RGB minus its mean over RGB)
    seed: int = 0
    threads: int = 1  # torch.set_num_threads
    base_dim: int = 16
    max_minutes: float = 0.0  # stop early after this wall time (0 = no limit)
    stop_at: int = 0  # stop after this step, the learning-rate schedule still spanning `steps` (0 = at `steps`)
    eval_every: int = 250  # held-out PSNR every N steps (0 = only at the end)
    eval_clips: int = 16  # held-out clips used for PSNR
    config: dict = field(default_factory=dict)  # AutoencoderKLWan overrides
    init: str = ""  # start from this train-vae output folder (fine-tuning, e.g. on longer windows)
    # decode a sample of the posterior (the textbook VAE) or its mean (ours, the default: evaluation and the DiT
    # use the mean, and after 300 sampled steps the posterior noise was still std ~0.3 against latents of rms ~1.3)
    sample_posterior: bool = False
    # extra weight of the squared error on moving pixels (ours): a pixel moves when it differs from the window's
    # per-pixel temporal median by more than 0.1 (in [-1, 1] units, any channel), dilated by one pixel. The arm
    # and the carried ball move; the floor, which is most of every frame, does not. 0 = plain MSE.
    foreground: float = 0.0
    # extra weight of the squared error on the ball's pixels (ours): the truth's pixels of the toy world's reserved
    # object colour (locate.OBJECT_TARGET), dilated by one pixel. The ball is 20-60 of 4096 pixels: plain and
    # moving-pixel MSE let the VAE blur it away where it is carried or half hidden. 0 = off.
    ball: float = 0.0
    # where the ball weight applies: "truth" (the truth's ball pixels only, as above) or "union" (those and the
    # reconstruction's own pixels of the ball's colour, dilated alike). With "truth" a ball-coloured smear away from
    # the ball costs only the plain MSE, and a VAE trained from scratch with --ball 20 painted the ball's colour
    # over 66-1464 pixels where the ball has 20-60; "union" weights those false pixels as much as missed ones.
    ball_region: str = "truth"
    # carry on from OUT's last checkpoint (OUT/vae + OUT/resume, :mod:`oscar_core.toyworld.vae_resume`) with the
    # same settings; only those in vae_resume.FREE_SETTINGS (steps, stop_at, ...) may differ
    resume: bool = False


def load_clip_frames(clipset, split: str, limit: int | None = None, embodiments=None) -> tuple[np.ndarray, list[str]]:
    """(N, T, H, W, 3) uint8 RGB of the clips whose ``meta.split`` is ``split`` (all same size), and their ids."""
    from ..train.clips import ClipSet

    cs = clipset if isinstance(clipset, ClipSet) else ClipSet(clipset)
    recs = [r for r in cs if r.meta.get("split") == split and (embodiments is None or r.embodiment in embodiments)]
    if limit is not None:
        recs = recs[:limit]
    if not recs:
        raise ValueError(f"{cs.root}: expected clips with meta.split == {split!r}, found none")
    frames = [cs.load(r, skeleton=False).rgb for r in recs]
    shapes = {f.shape for f in frames}
    if len(shapes) != 1:
        raise ValueError(f"{cs.root}: expected clips of one size, found {sorted(shapes)}")
    return np.stack(frames), [r.id for r in recs]


def chroma_ratio(pred: np.ndarray, truth: np.ndarray) -> float:
    """RMS chroma of ``pred`` over RMS chroma of ``truth`` (uint8 RGB arrays of one shape, (..., 3)).

    A pixel's chroma is its RGB minus the mean of its three channels; 1.0 means the
    reconstructions are as colourful as the truth, 0 means grey.
    """

    def rms(x):
        x = x.astype(np.float64)
        return float(np.sqrt(np.mean((x - x.mean(-1, keepdims=True)) ** 2)))

    return rms(pred) / max(rms(truth), 1e-12)


def moving_pixels(x, threshold: float = 0.1):
    """(B, 1, T, H, W) float mask of the pixels of ``x`` ((B, 3, T, H, W) in [-1, 1]) that move within the window.

    A pixel moves when any channel differs from its temporal median by more than ``threshold``; the mask is
    dilated by one pixel in space (3 x 3), so the edges of a moving part count too.
    """
    import torch

    med = x.median(dim=2, keepdim=True).values
    moving = ((x - med).abs().amax(1, keepdim=True) > threshold).float()
    return torch.nn.functional.max_pool3d(moving, (1, 3, 3), stride=1, padding=(0, 1, 1))


def ball_pixels(x):
    """(B, 1, T, H, W) float mask of the ball's pixels in ``x`` ((B, 3, T, H, W) in [-1, 1]): the toy world's
    reserved object colour (:func:`~oscar_core.toyworld.locate.ball_mask`), dilated by one pixel in space."""
    import torch

    from .locate import ball_mask

    u8 = ((x.detach().clamp(-1, 1) + 1.0) * 127.5).round().to(torch.uint8).permute(0, 2, 3, 4, 1).cpu().numpy()
    mask = torch.from_numpy(ball_mask(u8)).float().unsqueeze(1).to(x.device)
    return torch.nn.functional.max_pool3d(mask, (1, 3, 3), stride=1, padding=(0, 1, 1))


def false_ball_pixels(pred: np.ndarray, truth: np.ndarray) -> float:
    """Mean pixels per frame of the ball's colour in ``pred`` outside the truth's ball (its pixels of that colour,
    dilated by one pixel): the smear a ball weight on the truth's pixels alone does not penalise.

    pred, truth: (..., H, W, 3) uint8 of one shape. 0 for a reconstruction that adds no ball-coloured pixel.
    """
    from scipy.ndimage import binary_dilation

    from .locate import ball_mask

    p = ball_mask(pred.reshape(-1, *pred.shape[-3:]))
    t = ball_mask(truth.reshape(-1, *truth.shape[-3:]))
    t = binary_dilation(t, structure=np.ones((1, 3, 3), bool))
    return float((p & ~t).sum(axis=(1, 2)).mean())


def ball_kept(pred: np.ndarray, truth: np.ndarray, tol_px: float = 2.0) -> float | None:
    """Of the frames of ``truth`` that show the ball (at least 3 pixels of its colour), the fraction whose
    reconstruction in ``pred`` shows it too, its centroid within ``tol_px`` pixels of the truth's.

    pred, truth: (..., H, W, 3) uint8 of one shape. None when no truth frame shows the ball.
    """
    from .locate import BALL_TARGET, locate

    p, _ = locate(pred.reshape(-1, *pred.shape[-3:]), BALL_TARGET)
    t, _ = locate(truth.reshape(-1, *truth.shape[-3:]), BALL_TARGET)
    seen = ~np.isnan(t[:, 0])
    if not seen.any():
        return None
    with np.errstate(invalid="ignore"):
        near = np.linalg.norm(p[seen] - t[seen], axis=1) <= tol_px
    return float(np.mean(near))


def vae_psnr(vae, frames: np.ndarray, batch: int = 4) -> tuple[float, np.ndarray]:
    """Mean PSNR (dB, over clips and frames) of decode(encode(clip)) through ``VideoVAE``; and the reconstructions.

    vae: a ``WanVAE``; frames: (N, T, H, W, 3) uint8 with T = 4k + 1.
    """
    import torch

    from ..metrics import psnr
    from ..model.vae import VideoVAE

    vv = VideoVAE(vae)
    recs, scores = [], []
    with torch.no_grad():
        for i in range(0, len(frames), batch):
            x = VideoVAE.to_pixels(frames[i : i + batch])
            y = VideoVAE.to_uint8(vv.reconstruct(x))
            for a, b in zip(y, frames[i : i + batch]):
                s = psnr(a, b, n_frames=None)
                scores.append(np.minimum(s, 100.0).mean())
                recs.append(a)
    vae.train()
    return float(np.mean(scores)), np.stack(recs)


def _latent_stats(vae, frames: np.ndarray, batch: int = 4) -> tuple[list[float], list[float]]:
    import torch

    from ..model.vae import VideoVAE

    zs = []
    with torch.no_grad():
        for i in range(0, len(frames), batch):
            x = VideoVAE.to_pixels(frames[i : i + batch])
            zs.append(vae.encode(x).latent_dist.mode().float())
    z = torch.cat(zs).transpose(0, 1).reshape(vae.config.z_dim, -1)
    return z.mean(1).tolist(), z.std(1).clamp_min(1e-4).tolist()


def _new_or_initial_vae(cfg: VAETrainConfig):
    """``(vae, config)``: the VAE to train (``cfg.init``'s weights, or a new :class:`~oscar_core.model.wan_vae.WanVAE`
    of the toy config with ``cfg.base_dim`` and ``cfg.config``) and its config fields."""
    from ..model.wan_vae import WanVAE

    if cfg.init:
        vae = load_toy_vae(cfg.init)
        return vae, {k: vae.config[k] for k in TOY_VAE_CONFIG}
    config = {**TOY_VAE_CONFIG, "base_dim": cfg.base_dim, **cfg.config}
    return WanVAE(**config), config


def _training_batch(train: np.ndarray, rng: np.random.Generator, cfg: VAETrainConfig):
    """``cfg.batch`` random ``cfg.window``-frame windows of the (N, T, H, W, 3) uint8 clips, half of them flipped
    left-right, as a (B, 3, window, H, W) float32 tensor in [-1, 1]."""
    import torch

    N, T = train.shape[:2]
    idx = rng.integers(0, N, cfg.batch)
    starts = rng.integers(0, T - cfg.window + 1, cfg.batch)
    clip = np.stack([train[i, s : s + cfg.window] for i, s in zip(idx, starts)])
    flip = rng.uniform(size=cfg.batch) < 0.5  # horizontal flips: more views for free
    clip[flip] = clip[flip][:, :, :, ::-1]
    return torch.from_numpy(np.ascontiguousarray(clip)).permute(0, 4, 1, 2, 3).float().div(127.5).sub(1.0)


#: where --ball weights the squared error (VAETrainConfig.ball_region)
BALL_REGIONS = ("truth", "union")


def _vae_loss(vae, x, cfg: VAETrainConfig):
    """``(loss, mse, kl)`` of the VAE on the batch x (B, 3, T, H, W) in [-1, 1]: the reconstruction MSE, the KL per
    latent element times ``cfg.kl``, and the optional foreground (moving pixels) and chroma terms."""
    import torch

    post = vae.encode(x).latent_dist
    y = vae.decode(post.sample() if cfg.sample_posterior else post.mode()).sample
    err = (y - x) ** 2
    rec = torch.mean(err)
    kl = 0.5 * torch.mean(post.mean**2 + post.var - 1.0 - post.logvar)  # per latent element
    loss = rec + cfg.kl * kl
    if cfg.foreground:
        loss = loss + cfg.foreground * torch.mean(moving_pixels(x) * err)
    if cfg.ball:
        region = ball_pixels(x)
        if cfg.ball_region == "union":  # the reconstruction's ball-coloured pixels count too (no gradient in the mask)
            region = torch.maximum(region, ball_pixels(y))
        loss = loss + cfg.ball * torch.mean(region * err)
    if cfg.chroma:
        loss = loss + cfg.chroma * torch.mean(((y - y.mean(1, keepdim=True)) - (x - x.mean(1, keepdim=True))) ** 2)
    return loss, rec, kl


def _fraction(x: float | None) -> str:
    return "(no held-out frame shows the ball)" if x is None else f"{x:.3f}"


def _training_data(clipset, cfg: VAETrainConfig, log) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """``(train, held, held_ids)``: the (N, T, H, W, 3) uint8 train clips, the first ``cfg.eval_clips`` held-out
    clips and their ids; ValueError when the clips are shorter than ``cfg.window``."""
    t_load = time.perf_counter()
    train, _ = load_clip_frames(clipset, "train")
    held, held_ids = load_clip_frames(clipset, "heldout", limit=cfg.eval_clips)
    log(
        f"data: {len(train)} train clips {train.shape[1:]}, {len(held)} held-out clips "
        f"({time.perf_counter() - t_load:.1f} s to load)"
    )
    T = train.shape[1]
    if T < cfg.window:
        raise ValueError(f"--window: expected at most the clips' {T} frames, found {cfg.window}")
    return train, held, held_ids


def train_vae(clipset, out, cfg: VAETrainConfig, log: Callable[[str], None] | None = None) -> dict:
    """Train, evaluate and save; returns the card (also written to ``OUT/vae_card.json``).

    Progress: a bar over the steps (rate, ETA, the last training MSE) and the
    same lines as before at INFO on the ``oscar`` logger (or to ``log`` if given).
    """
    log = log or _log.info
    if cfg.ball_region not in BALL_REGIONS:
        raise ValueError(f"--ball-region: expected one of {', '.join(BALL_REGIONS)}, found {cfg.ball_region!r}")
    import torch

    from ..model.vae import check_frame_count

    check_frame_count(cfg.window, what="--window")
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    out = Path(out)
    _sweep_dead_save(out)  # a killed run's temporaries, before its state is read
    state = load_resume_state(out, cfg, clipset) if cfg.resume else None  # checked before any work
    train, held, held_ids = _training_data(clipset, cfg, log)
    vae, config = _new_or_initial_vae(cfg) if state is None else _resumed_vae(out)
    n_params = sum(p.numel() for p in vae.parameters())
    opt = torch.optim.AdamW(vae.parameters(), lr=cfg.lr, weight_decay=0.0)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda s: 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(s / max(cfg.steps, 1), 1.0)))
    )
    vae.train()
    curve, evals = [], []
    t0 = time.perf_counter()
    step = 0
    if state is not None:
        restore(state, opt, sched, rng)
        curve, evals, step = list(state["curve"]), list(state["evals"]), int(state["step"])
        t0 -= float(state["elapsed_s"])  # wall times continue the first run's
        log(f"resumed from step {step} of {out} (its resume/ matches vae/ by sha256)")

    def held_out_eval(step: int, wall_s: float | None = None) -> dict:
        """PSNR and chroma ratio of the held-out clips, appended to ``evals`` (wall_s: measured when None)."""
        p, recs = vae_psnr(vae, held)
        evals.append(
            {
                "step": step,
                "psnr_db": p,
                "chroma_ratio": chroma_ratio(recs, held),
                "ball_kept": ball_kept(recs, held),
                "false_ball_px": false_ball_pixels(recs, held),
                "wall_s": round(time.perf_counter() - t0, 1) if wall_s is None else wall_s,
            }
        )
        return evals[-1]

    if state is None:
        e0 = held_out_eval(0, wall_s=0.0)
        log(
            f"model: AutoencoderKLWan {config}, {n_params / 1e6:.2f} M parameters; held-out PSNR at step 0: "
            f"{e0['psnr_db']:.2f} dB, ball kept {_fraction(e0['ball_kept'])}"
        )
    stopped = "steps"
    bar = progress_bar(total=cfg.steps, initial=step, desc="toyworld train-vae", unit="step")
    while step < cfg.steps:
        loss, rec, kl = _vae_loss(vae, _training_batch(train, rng, cfg), cfg)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(vae.parameters(), 1.0)
        opt.step()
        sched.step()
        step += 1
        bar.update(1)
        wall = time.perf_counter() - t0
        if step % 25 == 0 or step == 1:
            bar.set_postfix(mse=f"{float(rec.detach()):.5f}", refresh=False)
            curve.append({"step": step, "mse": float(rec.detach()), "kl": float(kl.detach()), "wall_s": round(wall, 1)})
            log(
                f"step {step}/{cfg.steps}  mse {curve[-1]['mse']:.5f}  (≈ {10 * math.log10(4 / max(curve[-1]['mse'], 1e-12)):.2f} dB "
                f"train)  kl {curve[-1]['kl']:.4g}  {wall:.0f} s"
            )
        if cfg.eval_every and step % cfg.eval_every == 0 and step < cfg.steps:
            e = held_out_eval(step)
            log(
                f"step {step}: held-out PSNR {e['psnr_db']:.2f} dB, chroma ratio {e['chroma_ratio']:.3f}, "
                f"ball kept {_fraction(e['ball_kept'])}, false ball pixels {e['false_ball_px']:.1f} per frame"
            )
            resume = resume_state_files(opt, sched, rng, step, cfg, clipset, curve, evals, time.perf_counter() - t0)
            _save(vae, out, train, cfg, config, curve, evals, held_ids, n_params, t0, step, "checkpoint", resume)
        if cfg.stop_at and step >= cfg.stop_at:
            stopped = f"stop_at ({cfg.stop_at})"
            break
        if cfg.max_minutes and wall > 60 * cfg.max_minutes:
            stopped = f"max_minutes ({cfg.max_minutes:g})"
            break
    bar.close()
    e = evals[-1] if evals and evals[-1]["step"] == step else held_out_eval(step)  # stop_at on a checkpoint: done
    log(
        f"done: {step} steps, held-out PSNR {e['psnr_db']:.2f} dB, chroma ratio {e['chroma_ratio']:.3f}, "
        f"ball kept {_fraction(e['ball_kept'])}, false ball pixels {e['false_ball_px']:.1f} per frame, "
        f"{time.perf_counter() - t0:.0f} s (stopped by {stopped})"
    )
    resume = resume_state_files(opt, sched, rng, step, cfg, clipset, curve, evals, time.perf_counter() - t0)
    return _save(vae, out, train, cfg, config, curve, evals, held_ids, n_params, t0, step, stopped, resume)


def _resumed_vae(out: Path):
    """``(vae, config)`` of a resumed run: the checkpoint's weights (OUT/vae) and its config fields."""
    vae = load_toy_vae(out)
    return vae, {k: vae.config[k] for k in TOY_VAE_CONFIG}


def _sweep_dead_save(out: Path) -> None:
    """Undo what a save killed mid-way (:func:`_save`) left in ``out``: its temporaries (``.vae.tmp``,
    ``.resume.tmp``) are removed, and a folder it had renamed aside (``.vae.old``, ``.resume.old``) goes back to its
    name when nothing took its place (else it is removed). A vae/ and resume/ of different steps that this leaves
    are refused by ``--resume`` (the sha256 of the weights)."""
    import os
    import shutil

    for name in ("vae", "resume") if out.is_dir() else ():
        tmp, old = out / f".{name}.tmp", out / f".{name}.old"
        if tmp.exists():
            shutil.rmtree(tmp)
        if old.exists() and not (out / name).exists():
            os.replace(old, out / name)
        elif old.exists():
            shutil.rmtree(old)


def _save(vae, out: Path, train, cfg, config, curve, evals, held_ids, n_params, t0, step, stopped, resume) -> dict:
    """Write OUT/vae (the weights, with the latents' statistics), OUT/resume (the state to carry on from,
    :mod:`~oscar_core.toyworld.vae_resume`) and OUT/vae_card.json; returns the card. Each folder is written aside and
    renamed in, the old one renamed aside (``.NAME.old``) first and removed after; a killed save leaves its
    temporaries and, at worst, the previous folder aside, which :func:`_sweep_dead_save` clears and puts back."""
    import copy
    import os
    import shutil

    from ..model.configured import ModelConfig

    final = copy.deepcopy(vae).eval()
    mean, std = _latent_stats(final, train[:: max(1, len(train) // 32)][:32])  # 32 clips spread over the set
    # settings the network does not compute with (VideoVAE normalises latents by them): a new config, same weights
    final.config = ModelConfig({**final.config, "latents_mean": mean, "latents_std": std})
    out.mkdir(parents=True, exist_ok=True)
    _sweep_dead_save(out)
    tmp, tmp_state = out / ".vae.tmp", out / ".resume.tmp"
    final.save_pretrained(tmp, safe_serialization=True)
    write_files(tmp_state, finish_state(resume, weights_sha256(tmp)))
    for new, name in ((tmp, "vae"), (tmp_state, "resume")):
        old = out / f".{name}.old"
        if old.exists():
            shutil.rmtree(old)
        if (out / name).exists():
            os.replace(out / name, old)
        os.replace(new, out / name)
        if old.exists():
            shutil.rmtree(old)
    card = {
        "format": "oscar-toy-vae",
        "class": "AutoencoderKLWan",
        "config": config,
        "parameters": n_params,
        "settings": asdict(cfg),
        "steps_done": step,
        "stopped_by": stopped,
        "wall_s": round(time.perf_counter() - t0, 1),
        "heldout_clips": held_ids,
        "heldout_psnr_db": evals[-1]["psnr_db"],
        "heldout_chroma_ratio": evals[-1].get("chroma_ratio"),
        "evals": evals,
        "curve": curve,
    }
    atomic_write_bytes(out / "vae_card.json", (json.dumps(card, indent=2) + "\n").encode())
    return card


def load_toy_vae(folder):
    """The trained :class:`~oscar_core.model.wan_vae.WanVAE` from ``FOLDER/vae`` (or ``FOLDER`` itself), loaded
    strictly from safetensors."""
    from ..model.vae import load_vae_folder

    folder = Path(folder)
    if (folder / "vae").is_dir():
        folder = folder / "vae"
    return load_vae_folder(folder).eval()


def write_reconstructions(
    clipset, vae_folder, out, split: str | None = "heldout", limit: int | None = None, threads: int = 1
) -> list[str]:
    """Write decode(encode(clip)) of each clip (of ``split``) as ``OUT/<clip id>.npy`` ((T, H, W, 3) uint8).

    These are what ``oscar toyworld eval`` scores as the VAE's ceiling: no
    generated video can be closer to the truth than its own VAE's
    reconstruction. Returns the clip ids written.
    """
    import io

    import torch

    from ..model.vae import VideoVAE
    from ..train.clips import ClipSet

    torch.set_num_threads(threads)
    cs = ClipSet(clipset)
    vv = VideoVAE(load_toy_vae(vae_folder))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    from .rollouts import spread

    recs = spread([r for r in cs if split is None or r.meta.get("split") == split], limit)
    for r in progress_bar(recs, desc="toyworld reconstruct", unit="clip"):
        rgb = cs.load(r, skeleton=False).rgb
        with torch.no_grad():
            y = VideoVAE.to_uint8(vv.reconstruct(VideoVAE.to_pixels(rgb)))[0]
        buf = io.BytesIO()
        np.save(buf, y)
        atomic_write_bytes(out / f"{r.id}.npy", buf.getvalue())
    return [r.id for r in recs]
