"""Write toy-world episodes as a clip set (:mod:`oscar_core.train.clips`), deterministic per seed, resumable by shard.

Episode ``i`` of embodiment ``e`` depends only on (seed, e, i)
(:func:`~oscar_core.toyworld.episode.episode_rng`); episodes are grouped into
shards ``shard-<embodiment>-<k>`` of ``shard_size`` episodes, each written
atomically, and finished shards are skipped on a re-run, so a killed run
resumes where it stopped and produces the same files.

Each clip record carries the ground truth in ``meta.toyworld`` (docs/formats.md,
"Toy-world clips"): per-frame end-effector and object pixel positions and
visible areas, the attachment flags and the episode kind; ``meta.split`` is
``"heldout"`` for every tenth episode (index % 10 == 9) and ``"train"`` otherwise.
With ``pick_miss`` > 0 a fraction of the pick-and-place episodes miss the ball
(:func:`~oscar_core.toyworld.motion.miss_start`) and the ground truth adds
``missed`` and ``grabbed``; the default 0 writes exactly what it wrote before. ``pick_open`` (gripper never closes)
and ``pick_timing`` (it closes early or late, off the ball) add ``never_closed`` and ``mistimed`` the same way. With ``push`` the robots' balls move
under the push rule as well (:func:`~oscar_core.toyworld.motion.carry_object`; hands have their own push), recorded
as ``push_contact_radii`` in the fingerprint and in every record's ground truth (absent without it).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from .._util import stage as _stage
from .._util.log import get_logger, progress_bar
from ..train.clips import Clip, ClipRecord, ClipSetWriter, clip_openness
from .episode import episode_rng, make_episode, miss_rng
from .hand import HAND_MIN_FRAMES, HAND_SOURCE
from .motion import PUSH_CONTACT_RADII, ToyWorldError, check_supported, is_hand

__all__ = ["SOURCE", "GenerateConfig", "clip_id", "generate_clipset", "split_of"]

SOURCE = "toyworld"


@dataclass(frozen=True)
class GenerateConfig:
    """What to generate: ``episodes`` per embodiment of ``frames`` frames at ``width`` x ``height`` pixels."""

    embodiments: tuple[str, ...]
    episodes: int
    width: int = 64
    height: int = 64
    frames: int = 17
    fps: float = 10.0
    seed: int = 0
    shard_size: int = 50
    supersample: int = 2
    skeleton: bool = True  # also store the skeleton video (rendered at the RGB size)
    pick_miss: float = 0.0  # fraction of pick_place episodes whose ball lies out of reach (motion.miss_start)
    pick_open: float = 0.0  # fraction of the other pick_place episodes whose gripper never closes
    push: bool = False  # an open gripper pushes the ball (motion.carry_object's push rule); False: sets as before
    pick_timing: float = 0.0  # fraction of the on-ball picks whose gripper closes early or late (motion docstring)


def clip_id(embodiment: str, index: int) -> str:
    return f"{embodiment}-{index:06d}"


def split_of(index: int) -> str:
    """ "heldout" for every tenth episode (index % 10 == 9), else "train"."""
    return "heldout" if index % 10 == 9 else "train"


_log = get_logger(__name__)


def _checked_embodiments(cfg: GenerateConfig, registry) -> list:
    """The embodiments of ``cfg`` from ``registry``, with ``cfg``'s settings checked before anything is written:
    each embodiment supported (hands need ``HAND_MIN_FRAMES``), at least one episode, fractions in [0, 1]."""
    embs = [registry.get(n) for n in cfg.embodiments]
    for e in embs:
        check_supported(e, hands=True)
        if is_hand(e) and cfg.frames < HAND_MIN_FRAMES:
            raise ToyWorldError(
                f"toyworld generate: --frames: expected at least {HAND_MIN_FRAMES} frames for a hand episode "
                f"({e.name}), found {cfg.frames}"
            )
    if cfg.episodes < 1:
        raise ValueError(f"toyworld generate: --episodes: expected at least 1, found {cfg.episodes}")
    if not (isinstance(cfg.pick_miss, (int, float)) and 0.0 <= cfg.pick_miss <= 1.0):
        raise ToyWorldError(f"toyworld generate: --pick-miss: expected a fraction in [0, 1], found {cfg.pick_miss!r}")
    if not (isinstance(cfg.pick_open, (int, float)) and 0.0 <= cfg.pick_open <= 1.0):
        raise ToyWorldError(f"toyworld generate: --pick-open: expected a fraction in [0, 1], found {cfg.pick_open!r}")
    if not (isinstance(cfg.pick_timing, (int, float)) and 0.0 <= cfg.pick_timing <= 1.0):
        raise ToyWorldError(
            f"toyworld generate: --pick-timing: expected a fraction in [0, 1], found {cfg.pick_timing!r}"
        )
    if not isinstance(cfg.push, bool):
        raise ToyWorldError(f"toyworld generate: --push: expected True or False, found {cfg.push!r}")
    return embs


def _stage_parts(cfg: GenerateConfig) -> dict:
    """The clip set's fingerprint parts: what every episode depends on besides (seed, embodiment, index). A re-run
    with other settings into the same folder would mix episodes of two kinds; more episodes or embodiments only
    add shards, so they are left out."""
    return {
        "stage": "toyworld-generate",
        "format": _stage.FORMAT_VERSION,
        "seed": cfg.seed,
        "width": cfg.width,
        "height": cfg.height,
        "frames": cfg.frames,
        "fps": cfg.fps,
        "shard_size": cfg.shard_size,
        "supersample": cfg.supersample,
        "skeleton": cfg.skeleton,
        "pick_miss": cfg.pick_miss,
        **({"pick_open": cfg.pick_open} if cfg.pick_open > 0 else {}),  # absent: a set made before the option
        **({"pick_timing": cfg.pick_timing} if cfg.pick_timing > 0 else {}),  # the same
        **({"push_contact_radii": PUSH_CONTACT_RADII} if cfg.push else {}),  # absent: made without pushing
    }


def _episode_clip(cfg: GenerateConfig, emb, i: int):
    """``(clip, seconds)``: episode ``i`` of ``emb`` as a :class:`Clip` (its RGB video, trajectory, camera and, with
    ``cfg.skeleton``, the skeleton video; the ground truth in ``meta["toyworld"]``), and the seconds spent making
    and rendering it."""
    from ..render.skeleton_video import render_skeleton_video

    r0 = time.perf_counter()
    ep = make_episode(
        emb,
        episode_rng(cfg.seed, emb.name, i),
        cfg.width,
        cfg.height,
        cfg.frames,
        cfg.fps,
        ss=cfg.supersample,
        pick_miss=cfg.pick_miss,
        miss_rng=miss_rng(cfg.seed, emb.name, i),
        pick_open=cfg.pick_open,
        push=cfg.push,
        pick_timing=cfg.pick_timing,
    )
    skel = None
    if cfg.skeleton:
        skel = render_skeleton_video(emb, ep.trajectory, ep.camera)
    render_s = time.perf_counter() - r0
    openness = clip_openness(emb, ep.trajectory)
    meta = {
        "seed": cfg.seed,
        "episode": i,
        "split": split_of(i),
        "toyworld": ep.ground_truth(cfg.pick_miss > 0, cfg.pick_open > 0, cfg.pick_timing > 0),
    }
    if cfg.push and not is_hand(emb):
        meta["toyworld"]["push_contact_radii"] = PUSH_CONTACT_RADII
    rec = ClipRecord(
        id=clip_id(emb.name, i),
        source=HAND_SOURCE if is_hand(emb) else SOURCE,
        embodiment=emb.name,
        n_frames=cfg.frames,
        fps=cfg.fps,
        width=cfg.width,
        height=cfg.height,
        openness=tuple(tuple(float(v) for v in row) for row in openness),
        files={},
        caption=None,
        task=_task(ep.motion.kind),
        meta=meta,
    )
    return Clip(rec, rgb=ep.rgb, trajectory=ep.trajectory, camera=ep.camera, skeleton=skel), render_s


def generate_clipset(cfg: GenerateConfig, out, registry, progress: Callable[[str], None] | None = None) -> dict:
    """Generate (or resume) the clip set at ``out``; returns a summary with timings.

    registry: an :class:`~oscar_core.plugin.registry.Registry` (plugins included).
    A progress bar counts episodes (:func:`oscar_core._util.log.progress_bar`);
    each shard, written or already there, is logged at INFO with its own count of episodes and passed to
    ``progress`` if given.
    Unsupported embodiments are rejected before anything is written.
    """
    embs = _checked_embodiments(cfg, registry)
    writer = ClipSetWriter(out)  # first: a set of another format is refused before anything is recorded
    _stage.check_stage(out, _stage_parts(cfg), redo=f"use another --out for these settings, or delete {out} to redo it")
    writer.remove_stale()
    done = skipped = 0
    t0 = time.perf_counter()
    render_s = 0.0
    bar = progress_bar(total=cfg.episodes * len(embs), desc="toyworld generate", unit="episode")
    for emb in embs:
        n_shards = (cfg.episodes + cfg.shard_size - 1) // cfg.shard_size
        for k in range(n_shards):
            name = f"shard-{emb.name}-{k:06d}"
            lo, hi = k * cfg.shard_size, min((k + 1) * cfg.shard_size, cfg.episodes)
            if writer.shard_done(name):
                skipped += hi - lo
                bar.update(hi - lo)
                msg = f"{name}: {_episodes(hi - lo)} already there"
                _log.info(msg)
                if progress:
                    progress(msg)
                continue
            with writer.shard(name) as shard:
                for i in range(lo, hi):
                    clip, clip_s = _episode_clip(cfg, emb, i)
                    render_s += clip_s
                    shard.add(clip)
                    done += 1
                    bar.update(1)
            msg = f"{name}: {_episodes(hi - lo)} written"  # this shard's own count (the run's are in the summary)
            _log.info(msg)
            if progress:
                progress(msg)
    bar.close()
    wall = time.perf_counter() - t0
    return {
        "episodes_written": done,
        "episodes_skipped": skipped,
        "wall_s": wall,
        "render_s": render_s,
        "episodes_per_s": done / wall if done and wall > 0 else None,
    }


def _episodes(n: int) -> str:
    return f"{n} episode" if n == 1 else f"{n} episodes"


_TASKS = {
    "pick_place": "pick up the yellow ball and put it down elsewhere",
    "push": "push the yellow ball along the floor",
}


def _task(kind: str) -> str:
    return _TASKS.get(kind, "move the arm around")
