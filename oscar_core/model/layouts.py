"""Checkpoint layouts: which one a folder (or a Hub listing) holds, and loading each as an OSCAR model.

Three layouts load through the same front door (``oscar_zoo.load``):

* ``oscar`` — oscar's own export (``OscarWorldModel.save_pretrained``);
* ``diffusers`` — a diffusers pipeline folder or repo: ``transformer/``,
  ``vae/`` (and optionally ``scheduler/``), each with its config; the
  transformer is ``CosmosTransformer3DModel`` (PE_s zero, or found in the
  weights under a skeleton-like name) or ``OscarTransformer3DModel``;
* ``cosmos-native`` — NVIDIA's native DiT checkpoint (one ``.pt`` or
  ``.safetensors`` EMA state dict, keys mapped by :mod:`._native`) beside a
  diffusers ``vae/`` folder (the native release keeps its WAN 2.1 VAE as a
  pickle, which oscar never loads).

:func:`detect_layout` works on a list of relative paths, so the zoo decides
what to download from a Hub listing before fetching anything. When nothing
matches, the error lists the files found, the layouts tried and what each
expected.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from ._files import MODEL_FILE
from ._native import (
    NATIVE_SUFFIXES,
    find_skeleton_key,
    infer_config,
    map_native_state,
    read_native_state,
    read_overrides,
)
from .errors import CheckpointLayoutError
from .weights import CONFIG_NAME, INDEX_NAME, WEIGHTS_NAME, build_strict, load_state_dict, read_config

__all__ = ["LAYOUTS", "SCHEDULER_CONFIG", "Layout", "detect_layout", "load_folder"]

SCHEDULER_CONFIG = "scheduler/scheduler_config.json"
_COMPONENT_DIRS = ("transformer/", "vae/", "text_encoder/", "tokenizer/", "scheduler/", "text/", "safety_checker/")

#: layout → what it expects (for error messages and docs).
LAYOUTS = {
    "oscar": f"{MODEL_FILE}, transformer/{CONFIG_NAME} + {WEIGHTS_NAME} (or an index + shards), "
    f"vae/{CONFIG_NAME} + {WEIGHTS_NAME}",
    "diffusers": f"transformer/{CONFIG_NAME} + safetensors weights, vae/{CONFIG_NAME} + safetensors weights "
    f"(optional: {SCHEDULER_CONFIG})",
    "cosmos-native": "one DiT checkpoint (*.pt, *.pth or *.safetensors, e.g. *_ema_bf16.pt) outside the "
    f"component folders, plus a diffusers vae/ ({CONFIG_NAME} + safetensors weights)",
}


@dataclass
class Layout:
    """A detected layout: ``kind`` (a key of LAYOUTS) and the files it needs (relative paths)."""

    kind: str
    native_file: str | None = None
    report: list[str] = field(default_factory=list)


def _has_weights(files: set[str], sub: str) -> bool:
    return f"{sub}/{WEIGHTS_NAME}" in files or f"{sub}/{INDEX_NAME}" in files


def detect_layout(files, source, native_file: str | None = None) -> Layout:
    """The layout of a checkpoint holding ``files`` (relative POSIX paths); raises CheckpointLayoutError."""
    files = set(files)
    diffusers_ok = all(f"{s}/{CONFIG_NAME}" in files and _has_weights(files, s) for s in ("transformer", "vae"))
    if MODEL_FILE in files and diffusers_ok:
        return Layout("oscar")
    if diffusers_ok:
        return Layout("diffusers")
    natives = sorted(f for f in files if f.endswith(NATIVE_SUFFIXES) and not f.startswith(_COMPONENT_DIRS))
    if native_file is not None:
        natives = [f for f in natives if f == native_file]
    elif len(natives) > 1:
        ema = [f for f in natives if "ema" in Path(f).name.lower()]
        natives = ema or natives
    vae_ok = f"vae/{CONFIG_NAME}" in files and _has_weights(files, "vae")
    if len(natives) == 1 and vae_ok:
        return Layout("cosmos-native", native_file=natives[0])
    found = ", ".join(sorted(files)) or "no files"
    tried = "; ".join(f"{k}: {v}" for k, v in LAYOUTS.items())
    hint = ""
    partial = [s for s in ("transformer", "vae") if any(f.startswith(s + "/") for f in files)]
    if partial or MODEL_FILE in files:
        lacking = [f"{s}/{CONFIG_NAME}" for s in ("transformer", "vae") if f"{s}/{CONFIG_NAME}" not in files]
        lacking += [
            f"{s}/{WEIGHTS_NAME} (or {INDEX_NAME})" for s in ("transformer", "vae") if not _has_weights(files, s)
        ]
        hint = f"closest: {'oscar' if MODEL_FILE in files else 'diffusers'}, missing {', '.join(lacking)}"
    if len(natives) > 1:
        hint = f"several native checkpoints ({', '.join(natives)}): choose one with native_file=... / --native-file"
    elif natives and not vae_ok:
        hint = f"found the native checkpoint {natives[0]} but no diffusers vae/ beside it"
    raise CheckpointLayoutError(source, "layout", f"one of the layouts tried — {tried}", found, hint)


def list_folder(folder: Path) -> list[str]:
    """Relative POSIX paths of the files under ``folder`` (hidden ones skipped)."""
    return sorted(
        p.relative_to(folder).as_posix()
        for p in folder.rglob("*")
        if p.is_file() and not any(part.startswith(".") for part in p.relative_to(folder).parts)
    )


def _vae(folder: Path):
    from .vae import load_vae_folder

    return load_vae_folder(folder / "vae")


def _transformer_from_state(config: dict, state: dict, source, report: list[str], origin: dict | None = None):
    """OscarTransformer3DModel from a base (Cosmos) config + state; PE_s found under any plausible name or zero."""
    from .transformer import SKELETON_EMBED_KEY, OscarTransformer3DModel

    config = {k: v for k, v in config.items() if not k.startswith("_")}
    hidden = int(config["num_attention_heads"]) * int(config["attention_head_dim"])
    if SKELETON_EMBED_KEY in state:
        key = SKELETON_EMBED_KEY
    else:
        import torch

        with torch.device("meta"):
            probe = OscarTransformer3DModel.from_config({**config, "skeleton_channels": None})
        key = find_skeleton_key(state, set(probe.state_dict()), hidden, source)
    if key is None:
        report.append("skeleton embedder: none found in the weights; PE_s is zero (the base model)")
        config["skeleton_channels"] = None
        return build_strict(OscarTransformer3DModel, config, state, source, zero_missing=(SKELETON_EMBED_KEY,))
    weight = state.pop(key)
    vol = 1
    for p in config.get("patch_size", (1, 2, 2)):
        vol *= int(p)
    channels = weight.shape[1] // vol
    config["skeleton_channels"] = None if channels == int(config["out_channels"]) else channels
    state[SKELETON_EMBED_KEY] = weight
    report.append(f"skeleton embedder: {(origin or {}).get(key, key)} -> {SKELETON_EMBED_KEY} {tuple(weight.shape)}")
    return build_strict(OscarTransformer3DModel, config, state, source)


def load_folder(folder, layout: Layout | None = None, card=None, *, verify: bool = True, **options):
    """Load a local checkpoint folder of any layout as an ``OscarWorldModel``; returns (model, layout).

    card: ModelCard for layouts that carry none (diffusers, cosmos-native);
    options: ``OscarWorldModel.from_modules`` options (device, dtype, ...), and ``tiny_decoder`` and
    ``tiny_encoder`` (``OscarWorldModel.from_pretrained``'s: a file, or False).
    ``layout.report`` says what was found (skeleton embedder, scheduler).
    """
    from .world_model import ModelCard, OscarWorldModel

    folder = Path(folder)
    layout = layout or detect_layout(list_folder(folder), folder)
    if layout.kind == "oscar":
        model = OscarWorldModel.from_pretrained(folder, verify=verify, **options)
        layout.report.append(f"layout: oscar ({folder})")
        return model, layout
    report = layout.report
    tiny = options.pop("tiny_decoder", None)
    if tiny is not None and tiny is not False:
        from .tiny_decoder import load_tiny_decoder

        tiny = load_tiny_decoder(tiny)  # checked before the weights are read, as from_pretrained does
    encoder = options.pop("tiny_encoder", None)
    if encoder is not None and encoder is not False:
        from .tiny_encoder import load_tiny_encoder

        encoder = load_tiny_encoder(encoder)
    if layout.kind == "diffusers":
        from .transformer import OscarTransformer3DModel

        config = read_config(folder / "transformer", ("CosmosTransformer3DModel", "OscarTransformer3DModel"))
        if config.get("_class_name") == "OscarTransformer3DModel":
            transformer = OscarTransformer3DModel.load_strict(folder / "transformer")
            report.append("skeleton embedder: skeleton_embed.proj.weight (OscarTransformer3DModel)")
        else:
            transformer = _transformer_from_state(
                config, load_state_dict(folder / "transformer"), folder / "transformer", report
            )
        report.insert(0, f"layout: diffusers ({folder})")
    elif layout.kind == "cosmos-native":
        path = folder / layout.native_file
        origin: dict[str, str] = {}
        state = map_native_state(read_native_state(path), path, origin)
        config = infer_config(state, path, read_overrides(path))
        transformer = _transformer_from_state(config, state, path, report, origin)
        report.insert(0, f"layout: cosmos-native ({path}; keys mapped to diffusers' names)")
    else:
        raise CheckpointLayoutError(folder, "layout", " or ".join(LAYOUTS), repr(layout.kind))
    model = OscarWorldModel.from_modules(transformer, _vae(folder), card or ModelCard(), None, **options)
    if tiny is not None and tiny is not False:
        model.vae.use_tiny_decoder(tiny)
    if encoder is not None and encoder is not False:
        model.vae.use_tiny_encoder(encoder)
    scheduler = folder / SCHEDULER_CONFIG
    if scheduler.is_file():
        try:
            model.scheduler_config = json.loads(scheduler.read_text())
        except ValueError as exc:
            raise CheckpointLayoutError(scheduler, "JSON", "a JSON object", f"unreadable JSON ({exc})") from None
        report.append(f"scheduler: {model.scheduler_config.get('_class_name', '?')} from {SCHEDULER_CONFIG}")
    return model, layout
