"""Cache VAE latents in a clip set, so that training runs without the VAE in the loop.

``cache_latents(SRC, OUT, vae)`` copies every clip of the clip set ``SRC``
into ``OUT`` with a ``latents.safetensors`` added (docs/formats.md, "Training
clips"): the normalised latents of both streams for windows of ``window``
frames starting every ``stride`` frames, at the clip's own size. The condition
stream is the skeleton (the clip's stored skeleton video, else rendered from
trajectory + camera + embodiment) or another condition video of
:mod:`oscar_core.render.conditions` (``condition="mesh"`` or ``"capsules"``, rendered),
recorded in each file's metadata so the trainer uses it only for that condition. A clip shorter than the window gets no latents (the trainer then
encodes it on the fly or skips it, as its config says).

Work is per shard: a shard already finished in ``OUT`` is kept, so a killed
run resumes where it stopped and nothing is written twice.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["CacheSummary", "cache_latents", "window_starts"]


@dataclass
class CacheSummary:
    """What a run did: shards written and kept, clips with latents, clips without (too short), seconds."""

    out: str
    shards_written: int
    shards_kept: int
    clips_cached: int
    clips_too_short: int
    wall_s: float


def window_starts(n_frames: int, window: int, stride: int) -> np.ndarray:
    """(N,) int64 window starts 0, stride, 2·stride, … with start + window <= n_frames (empty when too short)."""
    if window < 1 or stride < 1:
        raise ValueError(f"window and stride: expected >= 1, found {window} and {stride}")
    if n_frames < window:
        return np.zeros(0, dtype=np.int64)
    return np.arange(0, n_frames - window + 1, stride, dtype=np.int64)


def _weights_digest(module) -> str:
    """sha256 of a module's state (names, shapes, dtypes and bytes, in order): what the cached latents depend on
    that a VAE config's hash does not say."""
    import hashlib

    import torch

    h = hashlib.sha256()
    for name, t in module.state_dict().items():
        t = t.detach().cpu().contiguous()
        h.update(f"{name}:{tuple(t.shape)}:{t.dtype};".encode())
        if t.numel():
            h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


def _vae_digest_name(vae) -> str:
    """The default ``vae_name``: ``config-sha256:`` and the first 16 hex digits of the sha256 of the VAE's config."""
    import hashlib
    import json

    cfg = json.dumps(dict(vae.vae.config), sort_keys=True, default=str)
    return "config-sha256:" + hashlib.sha256(cfg.encode()).hexdigest()[:16]


def _clips_by_shard(source, split: str | None) -> dict[Path, list]:
    """The records of ``source`` (a ClipSet) by the shard file holding them, those of ``split`` only when given."""
    by_shard: dict[Path, list] = {}
    for rec in source:
        if split is not None and rec.meta.get("split") != split:
            continue
        by_shard.setdefault(source.shard_of[rec.id], []).append(rec)
    return by_shard


def _encode_shard(source, recs, vae, registry, window: int, stride: int, batch: int, condition, condition_style):
    """Reads the clips ``recs`` of one shard and encodes every window of both streams, ``batch`` windows per VAE
    call. Returns ``(loaded, encoded)``: ``(rec, clip, starts)`` per clip (starts: (N,) int64 frame indices) and,
    per (clip index, ``"video"`` | ``"skeleton"``), the list of its windows' normalised latents, each (C, T', H', W')."""
    import torch

    loaded, windows = [], []
    for rec in recs:
        clip = source.load(rec, registry=registry)
        starts = window_starts(rec.n_frames, window, stride)
        skel = source.condition_video(rec, clip, registry, condition, condition_style) if len(starts) else None
        loaded.append((rec, clip, starts))
        windows += [(len(loaded) - 1, "video", clip.rgb[s : s + window]) for s in starts]
        windows += [(len(loaded) - 1, "skeleton", skel[s : s + window]) for s in starts]
    encoded: dict[tuple[int, str], list] = {}
    with torch.no_grad():
        for i in range(0, len(windows), batch):
            part = windows[i : i + batch]
            z = vae.encode(vae.to_pixels(np.stack([w for _, _, w in part])))
            for (k, role, _), zk in zip(part, z):
                encoded.setdefault((k, role), []).append(zk)
    return loaded, encoded


def _write_shard(writer, shard_name: str, loaded, encoded, window: int, vae_name: str, key) -> tuple[int, int]:
    """Writes one shard of ``OUT``: each clip of ``loaded``, with its latents from ``encoded`` when it has windows
    (see :func:`_encode_shard`). Returns ``(cached, too_short)``: the clips written with and without latents."""
    import torch

    from .clips import Clip

    cached = short = 0
    with writer.shard(shard_name) as sw:
        for k, (rec, clip, starts) in enumerate(loaded):
            if len(starts):
                clip = Clip(
                    rec,
                    rgb=clip.rgb,
                    trajectory=clip.trajectory,
                    camera=clip.camera,
                    skeleton=clip.skeleton,
                    prompt_embeds=clip.prompt_embeds,
                    latents={
                        "video": torch.stack(encoded[k, "video"]).float(),
                        "skeleton": torch.stack(encoded[k, "skeleton"]).float(),
                        "starts": starts,
                        "window": window,
                        "vae": vae_name,
                        "condition": key,
                    },
                )
                cached += 1
            else:
                short += 1
            sw.add(clip)
    return cached, short


def cache_latents(
    src,
    out,
    vae,
    window: int,
    stride: int | None = None,
    vae_name: str = "",
    split: str | None = None,
    batch: int = 8,
    registry=None,
    log: Callable[[str], None] = print,
    condition: str = "skeleton",
    condition_style: dict | None = None,
) -> CacheSummary:
    """Write ``OUT``: the clip set ``SRC`` with cached latents of ``window``-frame windows.

    vae: a :class:`~oscar_core.model.vae.VideoVAE`; window: frames per window
    (4k + 1); stride: frames between window starts (default: the window, i.e.
    non-overlapping); vae_name: recorded in each file's metadata (default: the
    VAE config's hash); split: copy only the clips whose ``meta.split`` is this
    (e.g. ``"train"``, leaving held-out clips out of training); batch: windows
    per VAE call (the toy VAE encodes 4x faster per clip at 16 than at 1;
    memory grows with it: 8 windows of 81 frames at 512x288 are ~1.2 GB of
    float32 pixels); condition: the condition video whose latents go in the
    condition stream (:data:`oscar_core.render.conditions.CONDITIONS`), drawn in ``condition_style`` (a mapping of
    style fields, the training config's ``condition_style``; None: the default look). Returns a
    :class:`CacheSummary`.
    """
    from .._util import stage as _stage
    from ..model.vae import check_frame_count
    from ..plugin.registry import Registry
    from ..render.conditions import check_condition, condition_key, style_for
    from .clips import ClipSet, ClipSetWriter

    check_frame_count(window, what="window")
    check_condition(condition, "--condition")
    style_for(condition, condition_style, "--condition-style")  # the one check of the style (fields, condition)
    key = condition_key(condition, condition_style)  # what the condition latents encode, as the trainer compares it
    if batch < 1:
        raise ValueError(f"batch: expected >= 1, found {batch}")
    stride = int(stride or window)
    source = ClipSet(src)
    if Path(out).resolve() == source.root.resolve():
        raise ValueError(f"{out}: expected an output folder other than the source clip set")
    registry = registry if registry is not None else Registry()
    vae_name = vae_name or _vae_digest_name(vae)
    parts = {
        "stage": "latent-cache",
        "format": _stage.FORMAT_VERSION,
        "source": str(source.root.resolve()),
        "vae": vae_name,
        "vae_weights": _weights_digest(vae.vae),
        "window": window,
        "stride": stride,
        "split": split,
        "condition": condition,
        **({"condition_style": condition_style} if condition_style else {}),  # a set made without it keeps its print
    }
    writer = ClipSetWriter(out)  # first: a cache of another format is refused before anything is recorded
    _stage.check_stage(out, parts, redo=f"use another --out for these settings, or delete {out} to redo it")
    writer.remove_stale()
    t0 = time.perf_counter()
    written = kept = cached = short = 0
    for shard, recs in sorted(_clips_by_shard(source, split).items()):
        if writer.shard_done(shard.name):
            kept += 1
            continue
        # read every clip of the shard, encode all windows of both streams in batches, then write the clips
        loaded, encoded = _encode_shard(source, recs, vae, registry, window, stride, batch, condition, condition_style)
        shard_cached, shard_short = _write_shard(writer, shard.name, loaded, encoded, window, vae_name, key)
        cached += shard_cached
        short += shard_short
        written += 1
        log(f"{shard.name}: {len(recs)} clips ({cached} cached so far, {time.perf_counter() - t0:.0f} s)")
    return CacheSummary(str(out), written, kept, cached, short, round(time.perf_counter() - t0, 1))
