"""``oscar eval benchmark run``: roll one world model out on every clip of a benchmark set.

Each clip is rolled out from its true first frame along its own trajectory
for the set's horizon (``settings.frames`` frames, the first one given):

* a skeleton-conditioned model sees the clip's stored skeleton video when it
  has one (what the model was trained on), else the skeleton rendered from the
  trajectory and camera at the clip's size;
* a model trained on another condition video (mesh, capsules) sees that rendering
  (:meth:`~oscar_core.model.world_model.OscarWorldModel.rollout_inputs`);
* a latent-action model gets the 14-D actions of the trajectory.

The prompt is the clip's stored ``prompt_embeds`` (``prompt="clip"``, the
default) when it has one, else the model's empty prompt (``prompt="empty"``
always uses the empty one).

Output, one folder per model (``DIR``): ``<clip id>.npy`` ((frames, H, W, 3)
uint8) and then ``<clip id>.json`` (the completion record: sampling seconds,
frames generated), each written atomically; a clip whose record exists is
skipped, so a killed run resumes. ``DIR/fingerprint.json`` holds the model's
identity and card, the sampler, the seed, the prompt mode and the set's
fingerprint: a run with other settings into the same ``DIR`` is refused
(:class:`oscar_core._util.stage.StageChanged`, naming what changed).

Speed: frames/s = frames generated (``frames - 1``: the first frame is the
input) / wall seconds of the rollout call (sampling, VAE encode and decode;
not reading the clip or writing the file).
"""

from __future__ import annotations

import dataclasses
import io
import json
import time
from pathlib import Path

import numpy as np

from .._util import stage as _stage
from .._util.atomic import atomic_write_bytes, sweep_dead_temporaries
from .._util.log import get_logger, progress_bar
from ..render.conditions import takes_actions, video_condition_of

__all__ = ["PROMPT_MODES", "rollout_clip", "run_benchmark", "read_timing"]

PROMPT_MODES = ("clip", "empty")
_log = get_logger(__name__)


def rollout_clip(
    model, clipset, rec, frames: int, *, sampler, seed: int = 0, registry=None, source=None, prompt: str = "clip"
) -> tuple[np.ndarray, float]:
    """One rollout: ``model`` from ``rec``'s first frame, conditioned on ``source``'s trajectory (default ``rec``).

    clipset: the :class:`~oscar_core.train.clips.ClipSet` holding both records;
    frames: how many frames to produce (the first one is the clip's own).
    Returns (video (frames, H, W, 3) uint8, seconds spent in the rollout call).
    """
    source = source or rec
    first = clipset.load(rec, frames=1, skeleton=False).rgb[0]
    clip = clipset.load(source, frames=frames, video=False, registry=registry)
    emb = registry.get(source.embodiment)
    embeds = None
    if prompt == "clip" and clip.prompt_embeds is not None:
        embeds = clip.prompt_embeds.reshape(1, *clip.prompt_embeds.shape[-2:])
    options = dict(sampler=sampler, seed=seed, progress=False, keep_chunks=False)
    t0 = time.perf_counter()
    if takes_actions(model.card.condition):
        acts = model.rollout_inputs(clip.trajectory, clip.camera, emb)["actions"][: frames - 1]
        video = model.rollout(first, None, embeds, actions=acts, **options)
    else:  # the card's condition video: the stored skeleton, or the mesh / capsules rendered
        name = video_condition_of(model.card.condition)
        style = getattr(model.card, "condition_style", None)  # a card of any model with rollout(), or an oscar card
        cond = clipset.condition_video(source, clip, registry, name, style)[:frames]
        from ..model.gripper_signal import gripper_input

        options.update(gripper_input(model.card, emb, clip.trajectory, frames))  # the same trajectory's openness
        video = model.rollout(first, cond, embeds, **options)
    seconds = time.perf_counter() - t0
    return np.asarray(video.frames if hasattr(video, "frames") else video).astype(np.uint8), seconds


def read_timing(folder, clip_id: str) -> dict | None:
    """The completion record of ``clip_id`` in a run folder (seconds, frames generated), or None."""
    p = Path(folder) / f"{clip_id}.json"
    if not p.is_file():
        return None
    try:
        return json.loads(p.read_text())
    except ValueError:
        return None


def run_benchmark(
    model, bench: dict, out, *, sampler, seed: int = 0, prompt: str = "clip", registry=None, model_id: str | None = None
) -> dict:
    """Roll ``model`` out on every clip of ``bench`` (a loaded set) into ``out``; see the module.

    model_id: what names the weights (:func:`oscar_core._util.stage.model_identity`
    of the spec loaded). Returns written / kept counts and the mean frames/s of
    the rollouts made now.
    """
    from ..plugin.registry import Registry
    from ..train.clips import ClipSet

    if prompt not in PROMPT_MODES:
        raise ValueError(f"--prompt: expected one of {PROMPT_MODES}, found {prompt!r}")
    registry = registry if registry is not None else Registry()
    frames = int(bench["settings"]["frames"])
    card = model.card
    parts = {
        "stage": "benchmark-run",
        "format": _stage.FORMAT_VERSION,
        "model": model_id,
        "card": dataclasses.asdict(card) if dataclasses.is_dataclass(card) else repr(card),
        "set": bench["fingerprint"],
        "frames": frames,
        "sampler": dataclasses.asdict(sampler),
        "seed": seed,
        "prompt": prompt,
    }
    out = Path(out)
    _stage.check_stage(out, parts, redo=f"use another --out for these settings, or delete {out} to redo it")
    sweep_dead_temporaries(out)
    sets: dict[str, ClipSet] = {}
    written = kept = 0
    fps = []
    for entry in progress_bar(bench["clips"], desc="benchmark rollouts", unit="clip"):
        cid = entry["id"]
        if read_timing(out, cid) is not None and (out / f"{cid}.npy").is_file():
            kept += 1
            continue
        cs = sets.get(entry["clipset"]) or sets.setdefault(entry["clipset"], ClipSet(entry["clipset"]))
        video, seconds = rollout_clip(
            model, cs, cs.record(cid), frames, sampler=sampler, seed=seed, registry=registry, prompt=prompt
        )
        buf = io.BytesIO()
        np.save(buf, video)
        atomic_write_bytes(out / f"{cid}.npy", buf.getvalue())
        record = {
            "id": cid,
            "seconds": seconds,
            "frames_generated": frames - 1,
            "frames_per_s": (frames - 1) / seconds if seconds > 0 else None,
        }
        atomic_write_bytes(out / f"{cid}.json", (json.dumps(record) + "\n").encode())
        fps.append(record["frames_per_s"])
        written += 1
        _log.debug("%s: rollout %.2f s", cid, seconds)
    return {
        "written": written,
        "kept": kept,
        "clips": len(bench["clips"]),
        "frames_per_s": float(np.mean(fps)) if fps else None,
    }
