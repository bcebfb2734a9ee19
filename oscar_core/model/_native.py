"""Native Cosmos-Predict2.5 checkpoints: read the EMA state dict and map its keys to diffusers' names.

NVIDIA's release stores the DiT as one file (``*_ema_bf16.pt``, a torch
pickle of a state dict, or safetensors) with keys such as
``net.blocks.3.self_attn.q_proj.weight``. diffusers' conversion script
(``scripts/convert_cosmos_to_diffusers.py``, the Cosmos 2.0 / 2.5 table)
renames them: strip ``net.``, then apply an ordered list of substring
replacements, then drop bookkeeping tensors (``accum_*``, ``pos_embedder.*``,
``_extra_state``). :data:`NATIVE_RENAMES` restates that table; a test pins a
few full key pairs taken from it.

``.pt`` files are read with ``torch.load(weights_only=True)`` only (tensors
and plain containers; no code can run). The configuration is inferred from
tensor shapes (hidden size, heads from the q-norm width, layers, MLP ratio,
AdaLN-LoRA rank, text dims, learnable positions); what shapes cannot tell
(patch size, RoPE scale, padding-mask channel) defaults to diffusers'
``Cosmos-2.5-Predict-Base-2B`` entry and a ``config.json`` beside the file
overrides it.

The skeleton embedder (PE_s) of an OSCAR checkpoint in native naming is
looked for under any plausible name (a left-over 2-D weight whose name
mentions skeleton/skel/pose/kinematic/keypoint and whose output width is the
hidden size); what was found is reported, and none found means a base
checkpoint (PE_s zero).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import TYPE_CHECKING

from .errors import CheckpointLayoutError

if TYPE_CHECKING:  # imported where tensors are read (keeps `oscar zoo list` free of torch)
    import torch

__all__ = [
    "NATIVE_RENAMES",
    "NATIVE_SUFFIXES",
    "map_native_key",
    "map_native_state",
    "read_native_state",
    "infer_config",
    "find_skeleton_key",
    "COSMOS25_DEFAULTS",
]

NATIVE_SUFFIXES = (".pt", ".pth", ".safetensors")

#: Ordered substring replacements, native → diffusers (diffusers' Cosmos 2.0 / 2.5 conversion table).
NATIVE_RENAMES: tuple[tuple[str, str], ...] = (
    ("t_embedder.1", "time_embed.t_embedder"),
    ("t_embedding_norm", "time_embed.norm"),
    ("blocks", "transformer_blocks"),
    ("adaln_modulation_self_attn.1", "norm1.linear_1"),
    ("adaln_modulation_self_attn.2", "norm1.linear_2"),
    ("adaln_modulation_cross_attn.1", "norm2.linear_1"),
    ("adaln_modulation_cross_attn.2", "norm2.linear_2"),
    ("adaln_modulation_mlp.1", "norm3.linear_1"),
    ("adaln_modulation_mlp.2", "norm3.linear_2"),
    ("self_attn", "attn1"),
    ("cross_attn", "attn2"),
    ("q_proj", "to_q"),
    ("k_proj", "to_k"),
    ("v_proj", "to_v"),
    ("output_proj", "to_out.0"),
    ("q_norm", "norm_q"),
    ("k_norm", "norm_k"),
    ("mlp.layer1", "ff.net.0.proj"),
    ("mlp.layer2", "ff.net.2"),
    ("x_embedder.proj.1", "patch_embed.proj"),
    ("final_layer.adaln_modulation.1", "norm_out.linear_1"),
    ("final_layer.adaln_modulation.2", "norm_out.linear_2"),
    ("final_layer.linear", "proj_out"),
)
_DROP = (
    "accum_video_sample_counter",
    "accum_image_sample_counter",
    "accum_iteration",
    "accum_train_in_hours",
    "pos_embedder.seq",
    "pos_embedder.dim_spatial_range",
    "pos_embedder.dim_temporal_range",
    "_extra_state",
)
_PREFIXES = ("net_ema.", "net.")
_SKELETON_WORDS = ("skeleton", "skel", "pose", "kinematic", "keypoint")

#: What tensor shapes cannot tell, from diffusers' ``Cosmos-2.5-Predict-Base-2B`` conversion entry.
COSMOS25_DEFAULTS = dict(
    patch_size=(1, 2, 2), rope_scale=(1.0, 3.0, 3.0), concat_padding_mask=True, max_size=(128, 240, 240)
)


def map_native_key(key: str) -> str | None:
    """The diffusers name of a native key (prefix stripped, renames applied); None for bookkeeping tensors."""
    for prefix in _PREFIXES:
        if key.startswith(prefix):
            key = key[len(prefix) :]
            break
    if any(d in key for d in _DROP):
        return None
    for old, new in NATIVE_RENAMES:
        key = key.replace(old, new)
    return key


def _unwrap(obj, source) -> dict:
    import torch

    for wrapper in ("model", "module", "state_dict"):
        if isinstance(obj, dict) and wrapper in obj and isinstance(obj[wrapper], dict):
            obj = obj[wrapper]
    if not isinstance(obj, dict) or not all(isinstance(v, torch.Tensor) for v in obj.values()):
        kinds = sorted({type(v).__name__ for v in obj.values()}) if isinstance(obj, dict) else [type(obj).__name__]
        raise CheckpointLayoutError(
            source, "state dict", "a mapping of tensor names to tensors", f"values of type {', '.join(kinds)}"
        )
    return obj


def read_native_state(path) -> dict[str, torch.Tensor]:
    """Tensors of a native checkpoint file (.pt/.pth via ``torch.load(weights_only=True)``, or .safetensors)."""
    path = Path(path)
    if path.suffix == ".safetensors":
        from safetensors.torch import load_file

        from .weights import check_safetensors

        check_safetensors(path)
        return load_file(str(path), device="cpu")
    import torch

    try:
        obj = torch.load(str(path), map_location="cpu", weights_only=True, mmap=True)
    except Exception as exc:  # noqa: BLE001 - any refusal by the safe unpickler is a layout problem
        raise CheckpointLayoutError(
            path,
            "torch checkpoint",
            "a state dict loadable with weights_only=True",
            f"{type(exc).__name__}: {str(exc).splitlines()[0][:200]}",
        ) from None
    return _unwrap(obj, path)


def map_native_state(
    state: dict[str, torch.Tensor], source, origin: dict[str, str] | None = None
) -> dict[str, torch.Tensor]:
    """Native keys → diffusers keys; the EMA copy (``net_ema.``) wins when both it and ``net.`` are present.

    origin: filled with {diffusers key: native key} when given (for reports).
    """
    has_ema = any(k.startswith("net_ema.") for k in state)
    out: dict[str, torch.Tensor] = {}
    origin = {} if origin is None else origin
    for key, value in state.items():
        if has_ema and key.startswith("net."):
            continue
        new = map_native_key(key)
        if new is None:
            continue
        if new in out:
            raise CheckpointLayoutError(
                source, "keys", "one native key per diffusers key", f"{origin[new]} and {key} both map to {new}"
            )
        out[new], origin[new] = value, key
    return out


def find_skeleton_key(state: dict[str, torch.Tensor], expected: set[str], hidden: int, source) -> str | None:
    """The one left-over key that is PE_s's weight, or None; raises when several candidates compete."""
    candidates = [
        k
        for k, v in state.items()
        if k not in expected
        and k.endswith("weight")
        and v.ndim == 2
        and v.shape[0] == hidden
        and any(w in k.lower() for w in _SKELETON_WORDS)
    ]
    if len(candidates) > 1:
        raise CheckpointLayoutError(
            source,
            "skeleton embedder",
            "one weight named like skeleton/pose/kinematic of output width " + str(hidden),
            f"several: {', '.join(sorted(candidates))}",
        )
    return candidates[0] if candidates else None


def _count_blocks(state) -> int:
    ids = {int(m.group(1)) for k in state for m in [re.match(r"transformer_blocks\.(\d+)\.", k)] if m}
    return max(ids) + 1 if ids else 0


def infer_config(state: dict[str, torch.Tensor], source, overrides: dict | None = None) -> dict:
    """An ``OscarTransformer3DModel`` config from (diffusers-named) tensor shapes, plus ``overrides``."""
    need = (
        "patch_embed.proj.weight",
        "transformer_blocks.0.attn1.norm_q.weight",
        "transformer_blocks.0.ff.net.0.proj.weight",
        "transformer_blocks.0.norm1.linear_1.weight",
        "transformer_blocks.0.attn2.to_k.weight",
        "proj_out.weight",
    )
    missing = [k for k in need if k not in state]
    if missing:
        raise CheckpointLayoutError(
            source,
            "native keys",
            "a Cosmos-Predict2.5 DiT (after renaming: " + ", ".join(need) + ")",
            f"missing {', '.join(missing)}",
        )
    cfg = dict(COSMOS25_DEFAULTS)
    cfg.update(overrides or {})
    p_t, p_h, p_w = cfg["patch_size"]
    vol = p_t * p_h * p_w
    hidden = state["patch_embed.proj.weight"].shape[0]
    head_dim = state["transformer_blocks.0.attn1.norm_q.weight"].shape[0]
    text_dim = state["transformer_blocks.0.attn2.to_k.weight"].shape[1]
    pad = 1 if cfg["concat_padding_mask"] else 0
    inferred = dict(
        in_channels=state["patch_embed.proj.weight"].shape[1] // vol - pad,
        out_channels=state["proj_out.weight"].shape[0] // vol,
        num_attention_heads=hidden // head_dim,
        attention_head_dim=head_dim,
        num_layers=_count_blocks(state),
        mlp_ratio=state["transformer_blocks.0.ff.net.0.proj.weight"].shape[0] / hidden,
        text_embed_dim=text_dim,
        adaln_lora_dim=state["transformer_blocks.0.norm1.linear_1.weight"].shape[0],
        encoder_hidden_states_channels=text_dim,
    )
    if "crossattn_proj.0.weight" in state:
        w = state["crossattn_proj.0.weight"]
        inferred.update(
            use_crossattn_projection=True,
            crossattn_proj_in_channels=w.shape[1],
            encoder_hidden_states_channels=w.shape[0],
        )
    else:
        inferred.update(use_crossattn_projection=False)
    if "learnable_pos_embed.pos_emb_t" in state:
        inferred.update(
            extra_pos_embed_type="learnable",
            max_size=(
                state["learnable_pos_embed.pos_emb_t"].shape[0] * p_t,
                state["learnable_pos_embed.pos_emb_h"].shape[0] * p_h,
                state["learnable_pos_embed.pos_emb_w"].shape[0] * p_w,
            ),
        )
    else:
        inferred.update(extra_pos_embed_type=None)
    for key, value in inferred.items():
        cfg.setdefault(key, value)
        if key not in (overrides or {}):
            cfg[key] = value
    return cfg


def read_overrides(checkpoint: Path) -> dict:
    """``config.json`` beside a native checkpoint (keys of the DiT config), or {}."""
    path = checkpoint.parent / "config.json"
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except ValueError as exc:
        raise CheckpointLayoutError(path, "JSON", "a JSON object", f"unreadable JSON ({exc})") from None
    out = {k: v for k, v in data.items() if not k.startswith("_")}
    for key in ("patch_size", "rope_scale", "max_size"):
        if key in out:
            out[key] = tuple(out[key])
    return out
