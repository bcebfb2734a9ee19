"""Check a toy-world clip set written before ``toyworld generate`` kept a fingerprint against this run's settings.

Such a set has no ``fingerprint.json``, but every clip record says most of
what its episode was made with: ``meta.seed`` and ``meta.episode``, the size
(``width``, ``height``), ``n_frames``, ``fps``, a stored ``skeleton`` file or
not, and the shard it sits in (its index follows from the episode and the
shard size). ``--pick-miss`` shows too: miss fields (``missed``,
``grabbed``) are written only when it is above 0, and a pick-and-place
episode missed exactly when the first draw of its miss generator is below it,
so the records bound the fraction they were made with. The supersampling
factor (``supersample``) is recorded nowhere and cannot be checked.
"""

from __future__ import annotations

import re

from .._util.stage import Legacy
from ..train.clips import finished_clipset
from .episode import miss_rng

__all__ = ["check_legacy_clipset"]

CHECKED = ("seed", "width", "height", "frames", "fps", "shard_size", "skeleton", "pick_miss")
UNCHECKED = ("supersample",)


def check_legacy_clipset(out, cfg) -> Legacy:
    """Compare the finished shards of clip set ``out`` with ``cfg`` (a ``GenerateConfig``); see the module
    docstring. An empty or new folder gives ``Legacy()`` (nothing to check)."""
    clips = finished_clipset(out)
    if clips is None:
        return Legacy()
    found = Legacy(checked=list(CHECKED), unchecked=list(UNCHECKED))
    differ = found.differ
    draws: list[tuple[float, bool]] = []  # (first draw of the miss generator, missed) of pick-and-place episodes
    for rec in clips.records:
        seed, episode = rec.meta.get("seed"), rec.meta.get("episode")
        if seed != cfg.seed:
            differ("seed", seed, cfg.seed)
        for name, old, new in (("width", rec.width, cfg.width), ("height", rec.height, cfg.height),
                               ("frames", rec.n_frames, cfg.frames)):
            if old != new:
                differ(name, old, new)
        if float(rec.fps) != float(cfg.fps):
            differ("fps", rec.fps, cfg.fps)
        if ("skeleton" in rec.files) != bool(cfg.skeleton):
            differ("skeleton", "skeleton" in rec.files, bool(cfg.skeleton))
        shard = clips.shard_of[rec.id].name
        m = re.fullmatch(rf"shard-{re.escape(rec.embodiment)}-(\d+)", shard)
        if not isinstance(episode, int) or m is None or episode // cfg.shard_size != int(m[1]):
            differ("shard_size", f"{shard} holding episode {episode}", cfg.shard_size)
        world = rec.meta.get("toyworld") or {}
        if ("missed" in world) != (cfg.pick_miss > 0):
            differ("pick_miss", "above 0 (miss fields recorded)" if "missed" in world else "0 (no miss fields)",
                   cfg.pick_miss)
        elif "missed" in world and world.get("kind") == "pick_place" and isinstance(seed, int) \
                and isinstance(episode, int):
            draws.append((float(miss_rng(seed, rec.embodiment, episode).uniform()), bool(world["missed"])))
    if not any(m.startswith("pick_miss:") for m in found.mismatches) \
            and any(missed != (u < cfg.pick_miss) for u, missed in draws):
        lo = max((u for u, missed in draws if missed), default=0.0)
        hi = min((u for u, missed in draws if not missed), default=1.0)
        differ("pick_miss", f"a value in ({lo:.3f}, {hi:.3f}]", cfg.pick_miss)
    found.shards = len(set(clips.shard_of.values()))
    return found
