"""Training checkpoints through ``torch.distributed.checkpoint`` (DCP): tensors only, never a pickle of objects.

A run folder::

    RUN_DIR/config.yaml                      the resolved config (what --resume reads)
    RUN_DIR/metrics.jsonl                    one JSON object per logged step
    RUN_DIR/checkpoints/step-00001000/       DCP files (.metadata, __<rank>_0.distcp)
        oscar_checkpoint.json                step + size and sha256 of every DCP file; written last
    RUN_DIR/export/                          the zoo-loadable folder (oscar train export)

A checkpoint holds ``model`` (the trained weights), ``ema`` (their EMA),
``optim`` (AdamW moments and step counts), ``step`` (the optimiser steps
done: the data sampler's position, since each step's batch is a function
of (seed, step)), ``rng`` (the CPU generator's state; the loop draws all
its randomness from per-step generators) and the learning rate comes from
the step (warm-up, then constant). Under DDP the tensors are replicated;
under FSDP2 they are DTensor shards, and DCP reshards on load (an FSDP run
resumes on another process count, and exports in one process).

Saving writes into a hidden temporary folder renamed into place after the
index is written, so a killed save leaves no checkpoint rather than a
partial one. Loading checks every file's sha256 first: a corrupted
checkpoint is an error naming the file, before anything is modified.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import warnings
from pathlib import Path

import torch
import torch.distributed.checkpoint as dcp

from ..model.errors import CheckpointIntegrityError, CheckpointLayoutError
from ..model.manifest import sha256_file
from .parallel import DistInfo, barrier

__all__ = [
    "CHECKPOINT_INDEX",
    "checkpoint_dir",
    "checkpoint_step",
    "list_checkpoints",
    "latest_checkpoint",
    "save_checkpoint",
    "load_checkpoint",
    "load_weights",
    "verify_checkpoint",
]

CHECKPOINT_INDEX = "oscar_checkpoint.json"
_STEP = re.compile(r"^step-(\d{8})$")


def checkpoint_dir(run_dir, step: int) -> Path:
    return Path(run_dir) / "checkpoints" / f"step-{step:08d}"


def checkpoint_step(path) -> int:
    """The optimiser steps done when the checkpoint folder ``path`` (``step-NNNNNNNN``) was saved."""
    return int(_STEP.match(Path(path).name).group(1))


def list_checkpoints(run_dir) -> list[Path]:
    """Finished checkpoints of a run (those with an index), oldest first."""
    root = Path(run_dir) / "checkpoints"
    if not root.is_dir():
        return []
    found = [p for p in root.iterdir() if p.is_dir() and _STEP.match(p.name) and (p / CHECKPOINT_INDEX).is_file()]
    return sorted(found, key=checkpoint_step)


def latest_checkpoint(run_dir) -> Path:
    """The newest finished checkpoint of ``run_dir``; CheckpointLayoutError when there is none."""
    found = list_checkpoints(run_dir)
    if not found:
        raise CheckpointLayoutError(
            run_dir,
            "checkpoints",
            f"a folder checkpoints/step-NNNNNNNN/ with {CHECKPOINT_INDEX}",
            "none (not a run folder, or no checkpoint was saved yet)",
        )
    return found[-1]


@contextlib.contextmanager
def _quiet(single: bool):
    """DCP warns that it assumes one process when no process group exists: that is intended here."""
    with warnings.catch_warnings():
        if single:
            warnings.filterwarnings("ignore", message=".*torch.distributed is disabled.*", category=UserWarning)
        yield


def _state(model, optimizer, ema: dict, step: int) -> dict:
    from torch.distributed.checkpoint.state_dict import get_state_dict

    model_sd, optim_sd = get_state_dict(model, optimizer)
    return {
        "model": model_sd,
        "optim": optim_sd,
        "ema": ema,
        "step": torch.tensor(step, dtype=torch.int64),
        "rng": torch.get_rng_state(),
    }


def save_checkpoint(run_dir, step: int, model, optimizer, ema: dict, info: DistInfo, keep_last: int = 3) -> Path:
    """Save step ``step`` (every rank calls this); returns the checkpoint folder."""
    final = checkpoint_dir(run_dir, step)
    tmp = final.with_name(f".{final.name}.tmp")
    if info.main:
        # one trainer writes a run folder: any other step's temporary is a killed save's leftover
        for stale in final.parent.glob(".step-*.tmp") if final.parent.is_dir() else ():
            shutil.rmtree(stale, ignore_errors=True)
        tmp.mkdir(parents=True)
    barrier(info)
    with _quiet(not info.distributed):
        dcp.save(_state(model, optimizer, ema, step), checkpoint_id=str(tmp), no_dist=not info.distributed)
    barrier(info)
    if info.main:
        files = sorted(p.name for p in tmp.iterdir() if p.is_file())
        index = {
            "format": "oscar-train-checkpoint",
            "version": 1,
            "step": step,
            "world_size": info.world,
            "files": {f: {"size": (tmp / f).stat().st_size, "sha256": sha256_file(tmp / f)} for f in files},
        }
        (tmp / CHECKPOINT_INDEX).write_text(json.dumps(index, indent=2, sort_keys=True) + "\n")
        if final.exists():
            shutil.rmtree(final)
        os.replace(tmp, final)
        for old in list_checkpoints(run_dir)[:-keep_last]:
            shutil.rmtree(old, ignore_errors=True)
    barrier(info)
    return final


def verify_checkpoint(folder) -> dict:
    """Check a checkpoint's index and every file's size and sha256; returns the index."""
    folder = Path(folder)
    path = folder / CHECKPOINT_INDEX
    if not path.is_file():
        raise CheckpointLayoutError(folder, CHECKPOINT_INDEX, "a finished checkpoint with its index", "no index")
    try:
        index = json.loads(path.read_text())
        files = index["files"]
        step = int(index["step"])
    except (ValueError, KeyError, TypeError):
        raise CheckpointIntegrityError(
            path, "index", "a JSON object with step and files", "an unreadable index"
        ) from None
    for name, meta in sorted(files.items()):
        f = folder / name
        if not f.is_file():
            raise CheckpointIntegrityError(f, "file", f"present ({meta['size']} bytes)", "missing")
        if f.stat().st_size != meta["size"]:
            raise CheckpointIntegrityError(
                f,
                "size",
                f"{meta['size']} bytes",
                f"{f.stat().st_size} bytes",
                "the checkpoint is corrupted or partial",
            )
        if sha256_file(f) != meta["sha256"]:
            raise CheckpointIntegrityError(
                f, "sha256", meta["sha256"], sha256_file(f), "the checkpoint is corrupted; resume from an older one"
            )
    index["step"] = step
    return index


def load_checkpoint(folder, model, optimizer, ema: dict, info: DistInfo, verify: bool = True) -> int:
    """Restore model, optimiser, EMA and RNG in place (every rank); returns the step to continue from."""
    from torch.distributed.checkpoint.state_dict import set_state_dict

    if verify and info.main:
        verify_checkpoint(folder)
    barrier(info)
    state = _state(model, optimizer, ema, 0)
    try:
        with _quiet(not info.distributed):
            dcp.load(state, checkpoint_id=str(folder), no_dist=not info.distributed)
    except Exception as exc:  # noqa: BLE001 - DCP raises many kinds on bad files
        raise CheckpointIntegrityError(
            folder,
            "DCP checkpoint",
            "tensors matching the model and optimiser",
            f"{type(exc).__name__}: {str(exc).splitlines()[0][:300]}",
        ) from None
    set_state_dict(model, optimizer, model_state_dict=state["model"], optim_state_dict=state["optim"])
    torch.set_rng_state(state["rng"])
    return int(state["step"])


def load_weights(folder, model: torch.nn.Module, key: str = "ema", verify: bool = True) -> torch.nn.Module:
    """Load ``key`` ("ema" or "model") of a checkpoint into a plain (unwrapped) module, in one process."""
    if verify:
        verify_checkpoint(folder)
    state = {key: {n: p.detach().clone() for n, p in model.named_parameters()}}
    try:
        with _quiet(True):
            dcp.load(state, checkpoint_id=str(folder), no_dist=True)
    except Exception as exc:  # noqa: BLE001
        raise CheckpointIntegrityError(
            folder, key, f"the {key} weights of this model", f"{type(exc).__name__}: {str(exc).splitlines()[0][:300]}"
        ) from None
    with torch.no_grad():
        for n, p in model.named_parameters():
            p.copy_(state[key][n])
    return model
