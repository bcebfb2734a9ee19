"""Self forcing: training items whose first latent frame is the model's own, as chunk k ≥ 2 of a rollout sees it.

A world model trained only from clean first frames of the data meets, from its second chunk on, a first frame it
made itself: a little blurred, the ball a little off. The gap is the one Huang, Li, He, Zhou and Shechtman name in
"Self Forcing" (arXiv 2506.08009, 2025). Here it is closed in its simplest form, one chunk back: for a chosen item
(a function of its noise seed, so a resumed run and any process count choose the same ones) the model first
samples, without gradients, the clip's window that ends at the item's first frame (``window − 1`` frames earlier,
from that window's clean first frame and condition). The VAE decodes it to pixels clamped to [−1, 1] and re-encodes
its last frame alone, exactly as a rollout chains chunks, and that latent replaces the item's first latent frame.
The loss is unchanged, so the target stays the data's continuation: the model learns to carry on *from its own
frame* towards what truly happens next. Items whose clip has no such window are left as they are.

Two callers: distillation (``distill.self_forcing``, the student in its own few Euler steps, :mod:`.distill`) and
plain rectified-flow training (``flow.self_forcing``, the model being trained, sampled as its rollouts sample it).
"""

from __future__ import annotations

import contextlib
from dataclasses import replace

import torch

from ..model.sampler import SamplerConfig, sample_chunk
from .config import TrainConfigError
from .data import Batch
from .sampling import PlanItem

__all__ = ["self_forced", "own_first_frames", "check_previous_windows", "CHOICE_SALT", "CONTEXT_SALT"]

CHOICE_SALT = 0x5F0C  # seeds derived from an item's noise seed: whether it is self-forced, its context's noise
CONTEXT_SALT = 0xC0DE


def self_forced(item: PlanItem, fraction: float) -> bool:
    """Whether ``item`` is trained from the model's own first frame: a uniform draw from its noise seed below
    ``fraction`` (so every process count and a resumed run choose the same items)."""
    if fraction <= 0.0:
        return False
    if fraction >= 1.0:
        return True
    g = torch.Generator().manual_seed(item.noise_seed ^ CHOICE_SALT)
    return float(torch.rand((), generator=g)) < fraction


def own_first_frames(
    model,
    data,
    batch: Batch,
    items: list[PlanItem],
    fraction: float,
    sampler: SamplerConfig,
    device,
    *,
    condition: str,
    window: int,
    autocast=None,
    any_rank=None,
) -> tuple[Batch, int]:
    """(``batch`` with the first latent frame of its self-forced items replaced, how many were replaced).

    model: the DiT that samples the previous windows (called whole, ``project_once=False``, so a sharded model
    gathers its weights in each forward); data: the run's :class:`~.data.TrainData` (it says which windows exist,
    loads them and holds the VAE); batch: the loaded micro-batch of ``items``, z0 (B, C, T', h, w); fraction: the
    share of items chosen (:func:`self_forced`); sampler: how the previous window is sampled (its steps, guidance);
    with guidance the unconditional branch sees each item's dropped condition, as training's skeleton dropout makes
    it; window: the clip frames per item; any_rank: ``f(bool) -> bool``, whether any process samples this
    micro-batch (FSDP2 needs every process in the forward), None for one process. Each item's noise comes from its
    own seed. No gradient flows through the result.
    """
    back = window - 1
    chosen = [
        k for k, it in enumerate(items) if self_forced(it, fraction) and data.has_window(it.clip, it.start - back)
    ]
    context = [replace(items[k], start=items[k].start - back, drop=False) for k in chosen]
    if any_rank is not None and any_rank(bool(chosen)) and not chosen:
        # a rank with nothing to self-force samples its first item's own window and throws the result away
        context = [replace(items[0], drop=False)]
    if not context:
        return batch, 0
    prev = data.batch(context, condition)
    uncond = None
    if sampler.guidance is not None:
        uncond = data.batch([replace(it, drop=True) for it in context], condition).skeleton.to(device, torch.float32)
    generators = [torch.Generator().manual_seed(it.noise_seed ^ CONTEXT_SALT) for it in context]
    with torch.no_grad(), autocast or contextlib.nullcontext():
        latent = sample_chunk(
            model,
            prev.z0[:, :, :1].to(device, torch.float32),
            prev.skeleton.to(device, torch.float32),
            prev.text.to(device),
            sampler,
            generators=generators,
            uncond_skeleton=uncond,
            project_once=False,
        )
    if not chosen:
        return batch, 0
    with torch.no_grad():
        video = data.vae.decode(latent.float()).clamp(-1.0, 1.0)
        first = data.vae.encode(video[:, :, -1:]).to(batch.z0.dtype).cpu()
    z0 = batch.z0.clone()
    z0[chosen, :, :1] = first
    return replace(batch, z0=z0), len(chosen)


def check_previous_windows(fraction: float, field: str, data, window: int, source: str = "<config>") -> int:
    """How many of ``data``'s clips hold a window with another window ``window − 1`` frames before it (what a
    self-forced item needs); a :class:`TrainConfigError` naming ``field`` when ``fraction`` > 0 and none does."""
    if fraction <= 0:
        return 0
    back = window - 1
    n = 0
    for k, u in enumerate(data.clips):
        starts = u.starts if data.cached and u.starts is not None else [back]
        n += any(data.has_window(k, int(s)) and data.has_window(k, int(s) - back) for s in starts)
    if n == 0:
        raise TrainConfigError(
            source,
            field,
            f"clips with two windows {back} frames apart (at least {2 * back + 1} frames"
            + (", cached at both starts)" if data.cached else ")"),
            f"none among {len(data.clips)} clips",
        )
    return n
