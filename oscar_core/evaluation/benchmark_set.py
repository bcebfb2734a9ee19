"""``oscar eval benchmark build``: an evaluation set chosen from clip sets by the paper's rules.

The rules are :mod:`oscar_core.evaluation.benchmark_rules`; this module reads
the clip sets, applies them in order and writes the set file:

1. **split**: only clips with ``meta.split == split`` (``None``: every clip);
2. **forward window**: the end effector, projected through the clip's camera
   (sized to the clip), stays inside the image (``margin`` pixels clear of the
   edges) for frames ``[0, frames)``; a clip shorter than ``frames`` is dropped
   too. Every drop is a row with its reason and the first frame outside;
3. **quotas** per (embodiment, source) group, proportional to sqrt(N) with N
   the group's clip count after step 1 (its corpus in these clip sets),
   capped at the clips that passed step 2;
4. **near-duplicates**: per group, k-means on [caption embedding, motion
   magnitude] (:func:`~oscar_core.evaluation.benchmark_rules.dedup_features`),
   one representative per cluster. With ``clusters`` None (default) the group
   gets as many clusters as its quota, so the quota's clips are the group's
   most distinct ones; with ``clusters`` K, each group is first reduced to
   min(K, n) representatives (dedup), and the quota is then filled from them
   in a seeded random order (dropped by quota).

The caption embedding is the clip's stored ``prompt_embeds`` pooled over
tokens when it has one (``text="prompt"``, default), else the hashed
bag-of-words of its caption (or task) text; ``text="hash"`` always uses the
text. The set file (JSON, written atomically) lists the chosen clips (clip
set path + id, embodiment, source, frames), the counts per rule, the quota of
each group, every dropped clip with its reason, the settings, and the
fingerprint of all of it (the rollouts and the table check it).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._util import stage as _stage
from .._util.atomic import atomic_write_bytes
from .._util.inputs import read_text_file
from .._util.log import get_logger, progress_bar
from ..errors import InputFileError, OscarError
from . import benchmark_rules as rules

__all__ = ["SET_FORMAT", "BenchmarkSetError", "build_benchmark_set", "load_benchmark_set", "TEXT_MODES"]

SET_FORMAT = "oscar-benchmark-set"
TEXT_MODES = ("prompt", "hash")
_log = get_logger(__name__)


class BenchmarkSetError(OscarError, ValueError):
    """A benchmark set file is missing, malformed, or does not match the clip sets it names."""


def _group(rec) -> str:
    return f"{rec.embodiment}/{rec.source}"


def _caption_vector(cs, rec, text: str) -> np.ndarray:
    if text == "prompt" and "prompt_embeds" in rec.files:
        clip = cs.load(rec, frames=1, video=False, skeleton=False)
        return rules.pooled_embedding(clip.prompt_embeds.float().numpy())
    return rules.text_embedding(rec.caption or rec.task)


def _candidate_clips(sets, split: str | None):
    """``(records, owner)``: the clips of the clip sets (of ``split`` when given) and the set holding each id;
    :class:`BenchmarkSetError` for an id in two sets or no clip at all."""
    recs, owner = [], {}
    for cs in sets:
        for r in cs:
            if split is not None and r.meta.get("split") != split:
                continue
            if r.id in owner:
                raise BenchmarkSetError(
                    f"clip id {r.id!r} is in both {owner[r.id].root} and {cs.root}: expected ids "
                    "unique across the clip sets of one benchmark"
                )
            owner[r.id] = cs
            recs.append(r)
    if not recs:
        raise BenchmarkSetError(
            f"{', '.join(str(c.root) for c in sets)}: expected clips"
            + (f" with meta.split == {split!r}" if split else "")
            + ", found none"
        )
    return recs, owner


def _forward_window_pass(recs, owner, registry, frames: int, margin: float):
    """The forward-window rule: ``(passed, motion, dropped)``, the clips whose end effector stays ``margin``
    pixels inside the image for ``frames`` frames, their motion magnitude (clip id → end-effector path over the
    image diagonal) and one dropped row per other clip."""
    dropped, passed, motion = [], [], {}
    for r in progress_bar(recs, desc="benchmark: forward window", unit="clip"):
        if r.n_frames < frames:
            dropped.append({"id": r.id, "rule": "forward_window", "reason": f"{r.n_frames} frames < horizon {frames}"})
            continue
        clip = owner[r.id].load(r, frames=frames, video=False, skeleton=False, registry=registry)
        emb = registry.get(r.embodiment)
        cam = clip.camera
        if (cam.intrinsics.width, cam.intrinsics.height) != (r.width, r.height):
            cam = cam.resized(r.width, r.height)
        uv, front = rules.end_effector_pixels(emb, emb.check_trajectory(clip.trajectory), cam)
        out_at = rules.forward_window(uv, front, r.width, r.height, frames, margin)
        if out_at is not None:
            dropped.append(
                {
                    "id": r.id,
                    "rule": "forward_window",
                    "reason": f"end effector outside the image at frame {out_at}",
                    "frame": out_at,
                }
            )
            continue
        motion[r.id] = rules.motion_magnitude(uv, frames, r.width, r.height)
        passed.append(r)
    return passed, motion, dropped


def _choose_in_group(g: str, members: list, x: np.ndarray, q: int, clusters: int | None, seed: int):
    """``(chosen, dropped)``: group ``g``'s representatives (``members`` sorted by id, features x (N, D)) for its
    quota ``q`` — one per k-means cluster, then a seeded draw down to the quota when ``clusters`` is larger —
    and a dropped row (dedup or quota) for every other member."""
    dropped = []
    k = q if clusters is None else min(clusters, len(members))
    keep = rules.kmeans_representatives(x, k, seed=seed)
    kept = set(keep)
    for i, r in enumerate(members):
        if i in kept:
            continue
        twin = next((members[j].id for j in keep if np.allclose(x[i], x[j], rtol=0, atol=1e-9)), None)
        if clusters is None and twin is None:  # the quota's k-means picked another clip of its cluster
            dropped.append(
                {
                    "id": r.id,
                    "rule": "quota",
                    "reason": f"not the representative of its k-means cluster (quota {q} = {k} clusters in {g})",
                }
            )
        else:
            dropped.append(
                {
                    "id": r.id,
                    "rule": "dedup",
                    "reason": f"near-duplicate: not the representative of "
                    f"its k-means cluster ({k} clusters in {g})" + (f"; same features as {twin}" if twin else ""),
                }
            )
    if len(keep) > q:  # --clusters larger than the quota: a seeded random draw of the representatives
        rng = np.random.default_rng([seed, len(g)] + list(g.encode()))
        order = [keep[i] for i in rng.permutation(len(keep))]
        for i in order[q:]:
            dropped.append({"id": members[i].id, "rule": "quota", "reason": f"beyond the quota {q} of {g}"})
        keep = sorted(order[:q])
    return [members[i] for i in keep], dropped


def _set_document(chosen, owner, motion, sets, settings, counts, corpus, by_group, quotas, dropped) -> dict:
    """The benchmark set's JSON: its fingerprint (format, settings, clip sets, chosen clips), settings, counts,
    quotas per group, the chosen clips (with their motion) and every dropped clip with its rule and reason."""
    clips = [
        {
            "clipset": str(owner[r.id].root.resolve()),
            "id": r.id,
            "embodiment": r.embodiment,
            "source": r.source,
            "n_frames": r.n_frames,
            "motion": round(motion[r.id], 6),
        }
        for r in chosen
    ]
    parts = {
        "format": SET_FORMAT,
        "format_version": _stage.FORMAT_VERSION,
        "settings": settings,
        "clipsets": [str(c.root.resolve()) for c in sets],
        "clips": [[c["clipset"], c["id"]] for c in clips],
    }
    return {
        "format": SET_FORMAT,
        "format_version": _stage.FORMAT_VERSION,
        "fingerprint": _stage.fingerprint(parts),
        "settings": settings,
        "clipsets": parts["clipsets"],
        "counts": counts,
        "quotas": {
            g: {"corpus": corpus[g], "passed": len(by_group.get(g, [])), "quota": quotas[g]} for g in sorted(corpus)
        },
        "clips": clips,
        "dropped": sorted(dropped, key=lambda d: d["id"]),
    }


def build_benchmark_set(
    clipsets,
    out,
    total: int,
    *,
    frames: int = 49,
    clusters: int | None = None,
    seed: int = 0,
    split: str | None = "heldout",
    margin: float = 0.0,
    text: str = "prompt",
    registry=None,
) -> dict:
    """Choose ``total`` clips from ``clipsets`` (paths) by the rules of the module; write the set to ``out``.

    frames: the evaluation horizon (the paper's 49); margin: pixels kept clear
    of the image edges by the forward-window check; clusters: k-means clusters
    per group (None: the group's quota); split: ``meta.split`` to draw from
    (None: every clip); text: ``prompt`` or ``hash`` (see the module). Returns
    the set (the JSON written).
    """
    from ..plugin.registry import Registry
    from ..train.clips import ClipSet

    if total < 1 or frames < 2:
        raise ValueError(f"--total / --frames: expected at least 1 clip and 2 frames, found {total} and {frames}")
    if clusters is not None and clusters < 1:
        raise ValueError(f"--clusters: expected a positive count, found {clusters}")
    if text not in TEXT_MODES:
        raise ValueError(f"--text: expected one of {TEXT_MODES}, found {text!r}")
    registry = registry if registry is not None else Registry()
    sets = [ClipSet(p) for p in clipsets]
    recs, owner = _candidate_clips(sets, split)
    corpus: dict[str, int] = {}
    for r in recs:
        corpus[_group(r)] = corpus.get(_group(r), 0) + 1
    passed, motion, dropped = _forward_window_pass(recs, owner, registry, frames, margin)
    by_group: dict[str, list] = {}
    for r in passed:
        by_group.setdefault(_group(r), []).append(r)
    feats = {}
    for g, members in by_group.items():
        members.sort(key=lambda r: r.id)
        feats[g] = rules.dedup_features(
            np.stack([_caption_vector(owner[r.id], r, text) for r in members]),
            np.array([motion[r.id] for r in members]),
        )
    # a group offers its distinct clips only: an exact duplicate never fills a quota
    quotas = rules.sqrt_quotas(
        {g: rules.distinct_rows(feats[g]) if g in feats else 0 for g in corpus}, total, corpus=corpus
    )
    chosen = []
    for g in sorted(by_group):
        group_chosen, group_dropped = _choose_in_group(g, by_group[g], feats[g], quotas[g], clusters, seed)
        chosen += group_chosen
        dropped += group_dropped
    counts = {
        "candidates": len(recs),
        **{rule: sum(1 for d in dropped if d["rule"] == rule) for rule in ("forward_window", "dedup", "quota")},
        "chosen": len(chosen),
    }
    why = (
        f"{counts['candidates']} candidates: {counts['forward_window']} dropped by the forward window (horizon "
        f"{frames} frames, margin {margin}), {counts['dedup']} as near-duplicates"
    )
    if not chosen:
        raise BenchmarkSetError(
            f"{out}: expected a set of --total {total} clips, found no clip to choose ({why}); "
            "a shorter --frames or another --split may leave some"
        )
    if len(chosen) < total:
        _log.warning(
            "benchmark set %s: %d clips, %d short of --total %d (%s)", out, len(chosen), total - len(chosen), total, why
        )
    settings = {
        "frames": frames,
        "total": total,
        "clusters": clusters,
        "seed": seed,
        "split": split,
        "margin": margin,
        "text": text,
        "feature": "caption embedding + end-effector path / image diagonal",
    }
    data = _set_document(chosen, owner, motion, sets, settings, counts, corpus, by_group, quotas, dropped)
    atomic_write_bytes(out, (json.dumps(data, indent=1) + "\n").encode())
    _log.info("benchmark set %s: %d clips of %d candidates", out, len(chosen), len(recs))
    return data


def load_benchmark_set(path) -> dict:
    """Read and check a set file written by :func:`build_benchmark_set` (its fingerprint included)."""
    path = Path(path)
    if not path.is_file():
        raise BenchmarkSetError(f"{path}: expected a benchmark set file (oscar eval benchmark build), found no file")
    try:
        data = json.loads(read_text_file(path, "a benchmark set file (JSON written by oscar eval benchmark build)"))
    except InputFileError as exc:
        raise BenchmarkSetError(str(exc)) from None
    except ValueError as exc:
        raise BenchmarkSetError(f"{path}: expected JSON, found invalid JSON ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != SET_FORMAT:
        found = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise BenchmarkSetError(f"{path}: field 'format': expected {SET_FORMAT!r}, found {found!r}")
    for key in ("settings", "clipsets", "clips", "fingerprint"):
        if key not in data:
            raise BenchmarkSetError(f"{path}: field {key!r}: expected present, found missing")
    if not data["clips"]:
        raise BenchmarkSetError(
            f"{path}: field 'clips': expected at least one clip, found an empty set (build it "
            "again with a shorter --frames or more clips)"
        )
    parts = {
        "format": SET_FORMAT,
        "format_version": data.get("format_version"),
        "settings": data["settings"],
        "clipsets": data["clipsets"],
        "clips": [[c["clipset"], c["id"]] for c in data["clips"]],
    }
    if _stage.fingerprint(parts) != data["fingerprint"]:
        raise BenchmarkSetError(
            f"{path}: field 'fingerprint': expected the sha256 of its settings and clips, found "
            "another (the file was edited); build the set again"
        )
    data["path"] = str(path)
    return data
