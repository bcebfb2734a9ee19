"""The resume state of ``oscar toyworld train-vae``: what a killed run needs to carry on exactly where its last
checkpoint stood.

``OUT/resume/`` sits beside ``OUT/vae/`` (the weights) and is rewritten with it at every checkpoint:

- ``optimizer.safetensors``: AdamW's per-parameter tensors (``state.<i>.<name>``, ``i`` the parameter's index in
  ``vae.parameters()``) and torch's CPU generator state (``torch_rng``, uint8);
- ``state.json``: the step, the settings and the clip set (its path, and a digest of its shards' ``clips.jsonl``, so a
  moved clip set still resumes and a changed one does not) that produced the run, the optimiser's param groups and
  the learning-rate schedule's counters, numpy's generator state, the loss curve and held-out evaluations so far,
  the elapsed training seconds, and the sha256 of ``vae/diffusion_pytorch_model.safetensors``, so a ``resume/``
  that belongs to other weights (a crash between the two renames) is refused rather than mixed with them.

Only safetensors and JSON are read back: nothing is unpickled. A run resumed from step k and trained to N gives
the weights of a run trained to N without stopping, bit for bit, on the same machine and thread count (tested).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict
from pathlib import Path

from .._util.atomic import atomic_write_bytes
from .motion import ToyWorldError

__all__ = [
    "clipset_digest",
    "FREE_SETTINGS",
    "finish_state",
    "RESUME_FORMAT",
    "load_resume_state",
    "restore",
    "resume_state_files",
    "weights_sha256",
    "write_files",
]

RESUME_FORMAT = "oscar-toy-vae-resume"
#: Settings a resumed run may change: how far and how it runs, not what it learns. ``steps`` also sets the length
#: of the cosine schedule, so raising it on resume lifts the learning rate from that step on (the card records it).
FREE_SETTINGS = ("steps", "stop_at", "max_minutes", "threads", "eval_every", "eval_clips", "resume")
WEIGHTS_FILE = "diffusion_pytorch_model.safetensors"


def weights_sha256(vae_folder: Path) -> str:
    """sha256 (hex) of the weights file of a saved VAE folder."""
    return hashlib.sha256((Path(vae_folder) / WEIGHTS_FILE).read_bytes()).hexdigest()


def clipset_digest(clipset) -> str:
    """sha256 (hex) over the clip set's shard indexes (``shard-*/clips.jsonl``, by shard name): which clips it holds
    and their records, wherever the folder lies."""
    h = hashlib.sha256()
    for index in sorted(Path(clipset).glob("shard-*/clips.jsonl")):
        h.update(index.parent.name.encode() + b"\0" + index.read_bytes() + b"\0")
    return h.hexdigest()


def resume_state_files(opt, sched, rng, step: int, cfg, clipset, curve, evals, elapsed_s: float) -> dict:
    """``{file name: bytes}`` of ``resume/`` at ``step`` (``state.json`` still lacks ``weights_sha256``: the caller
    adds it once the weights are written, :func:`finish_state`)."""
    import torch
    from safetensors.torch import save

    sd = opt.state_dict()
    tensors = {"torch_rng": torch.get_rng_state()}
    for i, st in sd["state"].items():
        for name, value in st.items():
            tensors[f"state.{i}.{name}"] = torch.as_tensor(value).detach().clone().contiguous()
    sched_sd = {k: v for k, v in sched.state_dict().items() if k != "lr_lambdas"}
    state = {
        "format": RESUME_FORMAT,
        "version": 1,
        "step": step,
        "settings": asdict(cfg),
        "clips": str(Path(clipset).resolve()),
        "clips_digest": clipset_digest(clipset),
        "param_groups": sd["param_groups"],
        "scheduler": sched_sd,
        "numpy_rng": rng.bit_generator.state,
        "curve": curve,
        "evals": evals,
        "elapsed_s": round(elapsed_s, 3),
    }
    return {"optimizer.safetensors": save(tensors), "state.json": state}


def finish_state(files: dict, weights_sha: str) -> dict:
    """The files of :func:`resume_state_files` with ``state.json`` as bytes, naming the weights they go with."""
    state = {**files["state.json"], "weights_sha256": weights_sha}
    return {**files, "state.json": (json.dumps(state, indent=1) + "\n").encode()}


def write_files(folder: Path, files: dict) -> None:
    """Write ``{name: bytes}`` into ``folder`` (created), each file atomically."""
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        atomic_write_bytes(folder / name, data)


def _refuse(path: Path, field: str, expected: str, found) -> ToyWorldError:
    return ToyWorldError(f"{path}: {field}: expected {expected}, found {found}")


def load_resume_state(out, cfg, clipset) -> dict:
    """The checked resume state of the train-vae run in ``out`` for settings ``cfg`` on ``clipset``: the parsed
    ``state.json`` plus ``tensors`` (optimizer.safetensors). Raises :class:`ToyWorldError` (one line naming the file
    and field) when the folder has no resume state, belongs to other weights, another clip set, or other settings
    than ``cfg`` outside :data:`FREE_SETTINGS`."""
    from safetensors.torch import load_file

    out = Path(out)
    path = out / "resume" / "state.json"
    if not path.is_file():
        raise ToyWorldError(
            f"{out}: --resume: expected resume/state.json from an earlier train-vae run (written at each checkpoint "
            f"since 2026-11-30), found {'no such folder' if not out.is_dir() else 'none'}"
        )
    try:
        state = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise _refuse(path, "contents", "JSON", f"unreadable ({exc})") from None
    if state.get("format") != RESUME_FORMAT or state.get("version") != 1:
        raise _refuse(path, "format", f"{RESUME_FORMAT} version 1", f"{state.get('format')} {state.get('version')}")
    weights = out / "vae" / WEIGHTS_FILE
    if not weights.is_file():
        raise _refuse(weights, "file", "the weights the resume state goes with", "no such file")
    if weights_sha256(out / "vae") != state.get("weights_sha256"):
        raise _refuse(
            path, "weights_sha256", f"the sha256 of {weights}", "another (resume/ and vae/ are from different steps)"
        )
    if state.get("clips_digest") != clipset_digest(clipset):
        raise _refuse(
            path, "clips_digest", f"the digest of the clip set given now ({clipset})", f"another ({state.get('clips')})"
        )
    saved, given = state.get("settings", {}), asdict(cfg)
    for key in sorted(set(saved) | set(given)):
        if key not in FREE_SETTINGS and saved.get(key) != given.get(key):
            raise _refuse(
                path, f"settings.{key}", f"the resumed run's {saved.get(key)!r}", f"{given.get(key)!r} given now"
            )
    state["tensors"] = load_file(out / "resume" / "optimizer.safetensors")
    return state


def restore(state: dict, opt, sched, rng) -> None:
    """Put the optimiser, the schedule and both generators back as :func:`load_resume_state`'s ``state`` had them."""
    import torch

    tensors = state["tensors"]
    per_param: dict[int, dict] = {}
    for key, value in tensors.items():
        if key.startswith("state."):
            _, i, name = key.split(".", 2)
            per_param.setdefault(int(i), {})[name] = value
    opt.load_state_dict({"state": per_param, "param_groups": state["param_groups"]})
    sched.load_state_dict({**state["scheduler"], "lr_lambdas": [None] * len(opt.param_groups)})
    rng.bit_generator.state = state["numpy_rng"]
    torch.set_rng_state(tensors["torch_rng"])
