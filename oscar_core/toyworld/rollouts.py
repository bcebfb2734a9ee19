"""World-model predictions for the toy-world table: roll a model out on each clip under one skeleton condition.

Conditions (the rows of ``oscar toyworld eval``'s table):

* ``true``: the clip's own skeleton video (stored, else rendered from its
  trajectory + camera);
* ``shuffled``: the skeleton of another clip of the same embodiment (clip i
  takes clip i + 1's, cyclically within the embodiment, over the clips rolled
  out — the split, or its ``limit`` subset: a fixed derangement, so every clip
  gets a foreign skeleton unless it is its embodiment's only clip);
* ``zero``: the model's unconditional branch alone (the skeleton it was
  trained to see when the skeleton is dropped: ``guidance 0`` in the
  ``standard`` form, whatever skeleton is passed).

Each rollout is :func:`oscar_core.evaluation.benchmark_run.rollout_clip` (the
benchmark's): a model trained on another condition video (``mesh``,
``capsules``: its card says which) sees that rendering of the skeleton's trajectory. A latent-action model (card ``condition: latent_action``) gets the 14-D
actions of the same trajectory instead of its skeleton video (``zero``: its
unconditional branch, no actions). Every rollout starts from the clip's true first frame, runs ``n_frames``
frames in chunks of the model card's length, uses the empty (zero) prompt of
the toy model, and is seeded by ``seed`` (the same noise for every condition).
Predictions are written as ``OUT/<clip id>.npy`` ((T, H, W, 3) uint8), the
layout ``oscar toyworld eval`` reads; a clip already written is skipped, so a
killed run resumes. ``OUT/fingerprint.json`` records what the predictions
depend on (model identity and card, condition, split and limit, the clips
rolled out, sampler, seed, format version): a run with others into the same
``OUT`` is refused (:class:`oscar_core._util.stage.StageChanged`, naming what
changed) instead of mixing predictions; use another ``--out``, or delete it
to redo.
"""

from __future__ import annotations

import dataclasses
import io
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from .._util import stage as _stage
from .._util.atomic import atomic_write_bytes, sweep_dead_temporaries
from .._util.log import get_logger, progress_bar

__all__ = ["CONDITIONS", "skeleton_partners", "write_rollouts", "sampler_for_card", "spread"]

CONDITIONS = ("true", "shuffled", "zero")


def spread(records: list, limit: int | None) -> list:
    """At most ``limit`` of ``records``, every k-th (so every embodiment of a clip set is represented)."""
    if limit is None or len(records) <= limit:
        return list(records)
    return list(records[:: len(records) // limit][:limit])


def skeleton_partners(records) -> dict[str, str]:
    """clip id → the clip id whose skeleton the ``shuffled`` condition uses (next clip of the same embodiment).

    An embodiment with a single clip keeps its own (nothing to shuffle with).
    """
    by_emb: dict[str, list[str]] = {}
    for r in records:
        by_emb.setdefault(r.embodiment, []).append(r.id)
    out = {}
    for ids in by_emb.values():
        for i, cid in enumerate(ids):
            out[cid] = ids[(i + 1) % len(ids)]
    return out


_log = get_logger(__name__)


def sampler_for_card(
    card,
    steps: int | None = None,
    guidance: float | None = None,
    guidance_form: str | None = None,
    guidance_interval: tuple[float, float] | None = None,
    preset: str | None = None,
):
    """A ``SamplerConfig``: the given steps / guidance / form / preset, else the card's recommended ones
    (``card.sampler``), else the library's defaults (35 steps, guidance 6 in the diffusers form at every step);
    :func:`oscar_core.model.sampler.resolve_sampler`."""
    from ..model.card_sampler import resolve_sampler

    return resolve_sampler(
        getattr(card, "sampler", None),
        steps=steps,
        guidance=guidance,
        guidance_form=guidance_form,
        guidance_interval=guidance_interval,
        preset=preset,
    ).config


def write_rollouts(
    model,
    clipset,
    out,
    condition: str = "true",
    *,
    split: str | None = "heldout",
    limit: int | None = None,
    sampler=None,
    seed: int = 0,
    registry=None,
    log: Callable[[str], None] | None = None,
    model_id: str | None = None,
) -> dict:
    """Roll ``model`` (an ``OscarWorldModel``) out on every clip of ``split`` under ``condition``; see the module.

    limit: at most this many clips, every k-th of the split's (so every
    embodiment is represented). sampler: a :class:`~oscar_core.model.sampler.SamplerConfig` (default: the
    library's, 35 UniPC steps, guidance 6 diffusers form); for ``zero`` its
    guidance is replaced by the unconditional branch. model_id: what names the
    weights (``oscar_core._util.stage.model_identity`` of the spec loaded; None:
    the card alone). Returns a summary: clips written and kept, seconds per
    rollout. ``StageChanged`` when ``out`` holds predictions made under other
    settings (see the module docstring).
    """
    from ..evaluation.benchmark_run import rollout_clip
    from ..model.sampler import SamplerConfig
    from ..plugin.registry import Registry
    from ..train.clips import ClipSet

    if condition not in CONDITIONS:
        raise ValueError(f"condition: expected one of {CONDITIONS}, found {condition!r}")
    sampler = sampler or SamplerConfig()
    if condition == "zero":
        sampler = replace(sampler, guidance=0.0, guidance_form="standard", guidance_interval=None)
    registry = registry if registry is not None else Registry()
    cs = ClipSet(clipset)
    recs = spread([r for r in cs if split is None or r.meta.get("split") == split], limit)
    if not recs:
        raise ValueError(f"{cs.root}: expected clips with meta.split == {split!r}, found none")
    partner = skeleton_partners(recs)
    out = Path(out)
    card = model.card
    parts = {
        "stage": "toyworld-rollout",
        "format": _stage.FORMAT_VERSION,
        "model": model_id,
        "card": dataclasses.asdict(card) if dataclasses.is_dataclass(card) else repr(card),
        "condition": condition,
        "split": split,
        "limit": limit,
        "clips": {
            "set": str(Path(clipset).resolve()),
            "ids": [r.id for r in recs],
            "frames": [r.n_frames for r in recs],
        },
        "sampler": dataclasses.asdict(sampler),
        "seed": seed,
    }
    _stage.check_stage(out, parts, redo=f"use another --out for these settings, or delete {out} to redo it")
    sweep_dead_temporaries(out)
    written = kept = 0
    seconds = []
    bar = progress_bar(recs, desc=f"toyworld rollout ({condition})", unit="clip")
    for rec in bar:
        target = out / f"{rec.id}.npy"
        if target.is_file():
            kept += 1
            continue
        source = cs.record(partner[rec.id]) if condition == "shuffled" else rec
        frames, secs = rollout_clip(
            model,
            cs,
            rec,
            min(rec.n_frames, source.n_frames),
            sampler=sampler,
            seed=seed,
            registry=registry,
            source=source,
            prompt="empty",
        )
        seconds.append(secs)
        buf = io.BytesIO()
        np.save(buf, frames.astype(np.uint8))
        atomic_write_bytes(target, buf.getvalue())
        written += 1
        msg = f"{rec.id}: {condition} rollout {seconds[-1]:.2f} s"
        _log.debug(msg)
        if log:
            log(msg)
    bar.close()
    return {
        "condition": condition,
        "written": written,
        "kept": kept,
        "s_per_rollout": float(np.mean(seconds)) if seconds else None,
    }
