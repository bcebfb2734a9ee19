"""Check a latent cache written before ``cache_latents`` kept a fingerprint against this run's settings.

Such a cache has no ``fingerprint.json``, but its shards say what they were
made with: each ``latents.safetensors`` records ``window``, ``vae`` (the
VAE's name, by default a hash of its config) and ``condition`` in its
metadata and the window ``starts`` (the stride, given the clip's frame
count); each output shard is named after its source shard and holds that
shard's clips of one ``--split``. What no file records — the VAE's weights
and the source's frames — is checked by encoding the first cached window
of one clip again and comparing it with the stored latents.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .._util.stage import Legacy
from .clips import ClipSet, finished_clipset

__all__ = ["check_legacy_cache"]

CHECKED = ("window", "stride", "vae", "condition", "split", "source", "vae_weights")
#: stored and re-encoded latents of one window agree to this, relative to the stored latents' largest magnitude
#: (one window alone and in a batch of 8 differ by float rounding only)
REENCODE_RTOL = 1e-3


def _old_split(old_ids: set[str], recs: list) -> object:
    """The ``--split`` a shard holding ``old_ids`` of a source shard's records ``recs`` was made with, or ... if
    none."""
    if old_ids == {r.id for r in recs}:
        return None
    for value in sorted({str(r.meta.get("split")) for r in recs}):
        if old_ids == {r.id for r in recs if str(r.meta.get("split")) == value}:
            return value
    return ...


def check_legacy_cache(out, source: ClipSet, *, vae, vae_name: str, window: int, stride: int, split: str | None,
                       condition: str, registry, starts_of: Callable[[int], np.ndarray]) -> Legacy:
    """Compare the finished shards of cache ``out`` (from clip set ``source``) with this run; see the module
    docstring. starts_of: the (N,) window starts this run gives a clip of so many frames
    (:func:`~oscar_core.train.cache.window_starts`). An empty or new folder gives ``Legacy()`` (nothing to
    check)."""
    import torch
    from safetensors import safe_open

    cache = finished_clipset(out)
    if cache is None:
        return Legacy()
    found = Legacy(checked=list(CHECKED))
    differ = found.differ

    by_source_shard: dict[str, list] = {}
    for rec in source:
        by_source_shard.setdefault(source.shard_of[rec.id].name, []).append(rec)
    by_shard: dict[str, set[str]] = {}
    for rec in cache.records:
        by_shard.setdefault(cache.shard_of[rec.id].name, set()).add(rec.id)
    for name, ids in sorted(by_shard.items()):
        recs = by_source_shard.get(name, [])
        want = {r.id for r in recs if split is None or r.meta.get("split") == split}
        if ids != want:
            old = _old_split(ids, recs)
            if old is ...:
                differ("source", f"{name} holding {len(ids)} clips other than {source.root}'s", str(source.root))
            else:
                differ("split", old, split)
    first = None  # (record, stored video latents) of the first cached clip: re-encoded below
    for rec in cache.records:
        expected = starts_of(rec.n_frames)
        if "latents" not in rec.files:
            if len(expected):
                differ("window", f"more than {rec.n_frames} (clip {rec.id} has no latents)", window)
            continue
        with safe_open(str(cache.shard_of[rec.id] / rec.files["latents"]), "pt") as f:
            meta = f.metadata() or {}
            starts = f.get_tensor("starts").numpy()
            if first is None:
                first = (rec, f.get_tensor("video")[0])
        old_window = int(meta.get("window", -1))
        if old_window != window:
            differ("window", old_window, window)
        elif not np.array_equal(starts, expected):
            differ("stride", int(starts[1] - starts[0]) if len(starts) > 1 else f"more than {rec.n_frames - window}",
                   stride)
        if meta.get("vae") != vae_name:
            differ("vae", meta.get("vae"), vae_name)
        if meta.get("condition", "skeleton") != condition:
            differ("condition", meta.get("condition", "skeleton"), condition)
    if not found.mismatches and first is not None:
        rec, stored = first
        src_rec = next((r for r in source if r.id == rec.id), None)
        if src_rec is None:
            differ("source", f"clip {rec.id} (absent from {source.root})", str(source.root))
        else:
            clip = source.load(src_rec, registry=registry)
            with torch.no_grad():
                z = vae.encode(vae.to_pixels(clip.rgb[None, :window]))[0].float()
            scale = float(stored.abs().max()) or 1.0
            gap = float((z - stored.float()).abs().max())
            if not gap <= REENCODE_RTOL * scale:
                differ("vae_weights", f"other weights or source frames (clip {rec.id}, window 0 encodes to latents "
                       f"{gap / scale:.2g} of their scale away from the stored ones)", "this run's VAE and source")
    found.shards = len(by_shard)
    return found
