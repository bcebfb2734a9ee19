"""Reading model folders: config.json + safetensors weights, loaded strictly.

A model folder is what diffusers' ``save_pretrained`` writes::

    config.json
    diffusion_pytorch_model.safetensors                 (one file), or
    diffusion_pytorch_model.safetensors.index.json      (+ the shards it lists)

Weights are read only from safetensors (no pickle can run). The model is
built on the meta device and the weights are assigned into it, so nothing is
initialised twice; keys must match exactly, except the ones a caller allows to
be missing (PE_s when starting from base Cosmos weights), which are created
as zeros. Afterwards no parameter or buffer may remain on the meta device.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import TYPE_CHECKING

from .errors import CheckpointIntegrityError, CheckpointLayoutError

__all__ = [
    "CONFIG_NAME",
    "WEIGHTS_NAME",
    "INDEX_NAME",
    "weight_files",
    "check_safetensors",
    "read_config",
    "load_state_dict",
    "build_strict",
    "meta_tensors",
    "cast_model",
]

CONFIG_NAME = "config.json"
WEIGHTS_NAME = "diffusion_pytorch_model.safetensors"
INDEX_NAME = WEIGHTS_NAME + ".index.json"
_PICKLE_SUFFIXES = (".bin", ".pt", ".pth", ".ckpt", ".pkl")
_MAX_HEADER = 100 * 1024 * 1024

if TYPE_CHECKING:  # torch is imported where tensors are made: reading names and headers needs none (oscar zoo list)
    import torch


def _listing(folder: Path) -> str:
    if not folder.is_dir():
        return "no such folder"
    names = sorted(p.name for p in folder.iterdir())
    return ", ".join(names) if names else "an empty folder"


def weight_files(folder) -> list[Path]:
    """The safetensors files holding ``folder``'s weights (one file or the shards of an index)."""
    folder = Path(folder)
    single, index = folder / WEIGHTS_NAME, folder / INDEX_NAME
    if single.is_file():
        return [single]
    if index.is_file():
        try:
            weight_map = json.loads(index.read_text())["weight_map"]
        except (ValueError, KeyError, TypeError) as exc:
            raise CheckpointLayoutError(
                index, "weight_map", "a JSON object {tensor name: shard file}", f"unreadable index ({exc})"
            ) from None
        shards = sorted({folder / name for name in weight_map.values()})
        missing = [p.name for p in shards if not p.is_file()]
        if missing:
            raise CheckpointLayoutError(
                folder, "weight shards", f"every shard listed in {INDEX_NAME}", f"missing {', '.join(missing)}"
            )
        return shards
    pickles = [p.name for p in sorted(folder.glob("*")) if p.suffix in _PICKLE_SUFFIXES] if folder.is_dir() else []
    hint = (
        (
            f"only pickle-based weights ({', '.join(pickles)}) are there; oscar loads safetensors only and never "
            "unpickles a checkpoint"
        )
        if pickles
        else ""
    )
    raise CheckpointLayoutError(folder, "weights", f"{WEIGHTS_NAME} or {INDEX_NAME}", _listing(folder), hint)


def check_safetensors(path) -> dict:
    """Check the structure of a safetensors file without loading it; return its header.

    Detects truncated (partial) and garbled files: the 8-byte header length,
    the JSON header, every tensor's byte range inside the file, and the file
    size equal to the end of the last tensor.
    """
    path = Path(path)
    size = path.stat().st_size
    if size < 8:
        raise CheckpointIntegrityError(
            path,
            "safetensors header",
            "at least 8 bytes",
            f"a file of {size} bytes",
            "the file is partial; download it again",
        )
    with path.open("rb") as fh:
        (n,) = struct.unpack("<Q", fh.read(8))
        if n > min(size - 8, _MAX_HEADER):
            raise CheckpointIntegrityError(
                path,
                "safetensors header length",
                f"at most {size - 8} bytes",
                f"{n} bytes",
                "the file is partial or not a safetensors file",
            )
        try:
            header = json.loads(fh.read(n))
        except ValueError:
            raise CheckpointIntegrityError(
                path, "safetensors header", "a JSON object", "unreadable bytes", "the file is corrupted"
            ) from None
    end = 0
    for name, info in header.items():
        if name == "__metadata__":
            continue
        try:
            start, stop = (int(v) for v in info["data_offsets"])
        except (KeyError, TypeError, ValueError):
            raise CheckpointIntegrityError(
                path, f"tensor {name!r}", "data_offsets [start, end]", repr(info)[:80]
            ) from None
        end = max(end, stop)
    if 8 + n + end != size:
        raise CheckpointIntegrityError(
            path,
            "file size",
            f"{8 + n + end} bytes (header + tensor data)",
            f"{size} bytes",
            "the file is partial or corrupted; download it again",
        )
    return header


def read_config(folder, allowed_classes: tuple[str, ...]) -> dict:
    """Read ``folder/config.json`` and check its ``_class_name`` is one of ``allowed_classes``."""
    path = Path(folder) / CONFIG_NAME
    if not path.is_file():
        raise CheckpointLayoutError(folder, CONFIG_NAME, "a diffusers model config", _listing(Path(folder)))
    try:
        config = json.loads(path.read_text())
    except ValueError as exc:
        raise CheckpointLayoutError(path, "JSON", "a JSON object", f"unreadable JSON ({exc})") from None
    name = config.get("_class_name")
    if name not in allowed_classes:
        raise CheckpointLayoutError(path, "_class_name", " or ".join(allowed_classes), repr(name))
    return config


def load_state_dict(folder, check: bool = True, device="cpu") -> dict[str, torch.Tensor]:
    """All tensors of ``folder``'s safetensors weights, read straight onto ``device`` (default the CPU; a GPU
    skips the host copy)."""
    from safetensors.torch import load_file

    state = {}
    for path in weight_files(folder):
        if check:
            check_safetensors(path)
        state.update(load_file(str(path), device=str(device)))
    return state


def meta_tensors(model: torch.nn.Module) -> list[str]:
    """Names of parameters and buffers still on the meta device (should be none)."""
    named = list(model.named_parameters()) + list(model.named_buffers())
    return [name for name, t in named if t.device.type == "meta"]


def build_strict(cls, config: dict, state: dict[str, torch.Tensor], source, zero_missing: tuple[str, ...] = ()):
    """Build ``cls`` from ``config`` and assign ``state`` to it, keys matched exactly.

    zero_missing: keys allowed to be absent from ``state``; they are created
        as zeros (e.g. PE_s when starting from the base Cosmos weights).
    Raises CheckpointLayoutError naming missing/unexpected keys and shape
    mismatches; returns the model in eval mode on the CPU.
    """
    import torch

    with torch.device("meta"):
        model = cls.from_config(config)
    expected = model.state_dict()
    missing = sorted(set(expected) - set(state) - set(zero_missing))
    unexpected = sorted(set(state) - set(expected))
    if missing or unexpected:
        parts = []
        if missing:
            parts.append(f"missing {len(missing)} ({', '.join(missing[:6])}{', ...' if len(missing) > 6 else ''})")
        if unexpected:
            parts.append(
                f"unexpected {len(unexpected)} ({', '.join(unexpected[:6])}{', ...' if len(unexpected) > 6 else ''})"
            )
        raise CheckpointLayoutError(
            source, "weights", f"the {len(expected)} tensors of {cls.__name__}", "; ".join(parts)
        )
    bad = [
        f"{k} {tuple(state[k].shape)} (expected {tuple(v.shape)})"
        for k, v in expected.items()
        if k in state and tuple(state[k].shape) != tuple(v.shape)
    ]
    if bad:
        raise CheckpointLayoutError(source, "tensor shapes", "shapes matching config.json", "; ".join(bad[:4]))
    full = dict(state)
    ref_dtype = next(iter(state.values())).dtype if state else torch.float32
    for key in zero_missing:
        if key in expected and key not in state:
            full[key] = torch.zeros(expected[key].shape, dtype=ref_dtype)
    model.load_state_dict(full, strict=True, assign=True)
    left = meta_tensors(model)
    if left:
        raise CheckpointLayoutError(source, "tensors left on the meta device", "none", ", ".join(left[:8]))
    return model.eval()


def cast_model(model: torch.nn.Module, device=None, dtype: torch.dtype | None = None) -> torch.nn.Module:
    """Move ``model`` to ``device``/``dtype``; its keep-in-float32 modules stay float32."""
    import torch

    kwargs = {k: v for k, v in (("device", device), ("dtype", dtype)) if v is not None}
    if kwargs:  # plain nn.Module.to: diffusers' override only adds a warning about float32 modules we handle here
        torch.nn.Module.to(model, **kwargs)
    if dtype is not None and dtype != torch.float32:
        keep = (
            getattr(model, "_oscar_keep_in_fp32_modules", None) or getattr(model, "_keep_in_fp32_modules", None) or []
        )
        for name, module in model.named_modules():
            if any(name == k or name.startswith(k + ".") for k in keep):
                module.to(torch.float32)
    return model
