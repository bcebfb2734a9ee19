"""How much device memory a training step needs (computed), and the activation-checkpointing choice it drives.

The model (bytes per process; P parameters, N processes sharing the state under FSDP, else N = 1):

* training state: fp32 weights 4P + fp32 gradients 4P + AdamW moments 8P + fp32 EMA 4P = 20P / N;
* bf16 weight copies made by autocast (``model.dtype: bfloat16``): 2P — autocast caches the bf16 cast of every
  weight for the whole forward and the matmuls save them for backward; counted whole (an upper bound under FSDP);
* AdamW's temporaries: the foreach implementation (PyTorch's default on CUDA) builds one fp32 list the size of
  the parameters (``sqrt`` of the second moment), 4P / N; the fused one builds none;
* FSDP: the all-gathered fp32 weights of two blocks (the current and the prefetched one), 8 × block parameters;
* activations per clip: without checkpointing, ``ACT_BYTES_PER_TOKEN_PER_WIDTH`` × hidden × tokens per block,
  for every block (twice that without bf16 autocast); with checkpointing each block keeps only its fp32 input
  (4 × hidden bytes per token) plus one block's full activations during its recomputation.

``ACT_BYTES_PER_TOKEN_PER_WIDTH`` is measured by ``benchmarks/train.py``: the bytes autograd saves for backward
in one 2B-width block (hidden 2048) under bf16 autocast, counted with ``saved_tensors_hooks`` on the CPU —
332,547 bytes per token, 162.4 per token per unit of width. Every figure here is *computed*, not measured on a
GPU.

``activation_checkpointing: auto`` picks ``none`` when the step without checkpointing fits in 90 % of the
device's free memory, else ``full``; on the CPU it is ``none`` (host memory is not the limit it is on a GPU).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch

from .config_checks import CHECKPOINTING

__all__ = [
    "ACT_BYTES_PER_TOKEN_PER_WIDTH",
    "CHECKPOINTING",
    "FREE_FRACTION",
    "MemoryEstimate",
    "choose_checkpointing",
    "estimate_memory",
    "free_device_memory",
    "model_estimate",
    "tokens_per_clip",
]

#: autograd-saved bytes per token per block per unit of hidden width, bf16 autocast (benchmarks/train.py: 332547 / 2048)
ACT_BYTES_PER_TOKEN_PER_WIDTH = 332547 / 2048
FREE_FRACTION = 0.9  # of the free memory a step may plan on (the rest: allocator fragmentation, CUDA workspaces)


@dataclass(frozen=True)
class MemoryEstimate:
    """Bytes per process of one training step (module docstring); ``total(checkpointing)`` adds them up."""

    state: float
    autocast_weights: float
    optimizer_temporaries: float
    gathered: float
    activations_none: float
    activations_full: float

    def total(self, checkpointing: str) -> float:
        act = self.activations_full if checkpointing == "full" else self.activations_none
        return self.state + self.autocast_weights + self.optimizer_temporaries + self.gathered + act

    def as_dict(self) -> dict:
        return {**asdict(self), "total_none": self.total("none"), "total_full": self.total("full")}


def tokens_per_clip(window: int, width: int, height: int, patch=(1, 2, 2), temporal: int = 4, spatial: int = 8) -> int:
    """DiT tokens of one clip: latent frames x latent rows x latent columns, divided by the patch."""
    frames = (window - 1) // temporal + 1
    return (frames // patch[0]) * (height // spatial // patch[1]) * (width // spatial // patch[2])


def estimate_memory(
    params: int,
    block_params: int,
    layers: int,
    hidden: int,
    tokens: int,
    *,
    micro_batch: int = 1,
    shards: int = 1,
    bf16_autocast: bool = True,
    fused_adamw: bool = False,
) -> MemoryEstimate:
    """The step's memory per process in bytes (module docstring); ``shards``: processes sharing the state (FSDP)."""
    per_token_block = ACT_BYTES_PER_TOKEN_PER_WIDTH * hidden * (1 if bf16_autocast else 2)
    clips_tokens = tokens * micro_batch
    return MemoryEstimate(
        state=20 * params / shards,
        autocast_weights=2 * params if bf16_autocast else 0.0,
        optimizer_temporaries=0.0 if fused_adamw else 4 * params / shards,
        gathered=8 * block_params if shards > 1 else 0.0,
        activations_none=per_token_block * clips_tokens * layers,
        activations_full=4 * hidden * clips_tokens * layers + per_token_block * clips_tokens,
    )


def free_device_memory(device) -> int | None:
    """Free bytes on a CUDA ``device`` (``torch.cuda.mem_get_info``); None elsewhere."""
    device = torch.device(device)
    if device.type != "cuda":
        return None
    return int(torch.cuda.mem_get_info(device)[0])


def model_estimate(model, config, shards: int = 1, compression: tuple[int, int] = (4, 8)) -> MemoryEstimate:
    """:func:`estimate_memory` of a built transformer under a TrainConfig (its window, size and dtype).

    compression: the VAE's (temporal, spatial) compression, e.g. (4, 8) for WAN 2.1, (4, 4) for the toy world's.
    """
    params = sum(p.numel() for p in model.parameters())
    blocks = list(model.transformer_blocks)
    block_params = sum(p.numel() for p in blocks[0].parameters()) if blocks else 0
    cfg = model.config
    hidden = int(cfg.num_attention_heads) * int(cfg.attention_head_dim)
    d = config.data
    tokens = tokens_per_clip(d.window, d.width, d.height, tuple(cfg.patch_size), *compression)
    return estimate_memory(
        params,
        block_params,
        len(blocks),
        hidden,
        tokens,
        micro_batch=config.micro_batch,
        shards=shards,
        bf16_autocast=config.model.dtype == "bfloat16",
    )


def choose_checkpointing(
    config, model, device, shards: int = 1, compression: tuple[int, int] = (4, 8)
) -> tuple[str, str]:
    """("none" or "full", why) for ``config``'s activation-checkpointing policy on ``device``.

    ``auto``: ``none`` on a non-CUDA device, else ``none`` when :func:`model_estimate`'s step without checkpointing fits in 90 % of
    :func:`free_device_memory` (measured now, before the model moves there), else ``full``.
    """
    policy = config.activation_checkpointing
    if policy in ("none", "full"):
        return policy, f"activation_checkpointing: {policy}"
    free = free_device_memory(device)
    if free is None:
        return "none", f"activation_checkpointing: auto: none on {torch.device(device).type} (not a GPU)"
    est = model_estimate(model, config, shards, compression)
    need, budget = est.total("none"), FREE_FRACTION * free
    gib = 1024**3
    if need <= budget:
        return "none", (
            f"activation_checkpointing: auto: none (a step needs ~{need / gib:.1f} GiB computed, "
            f"{free / gib:.1f} GiB free)"
        )
    return "full", (
        f"activation_checkpointing: auto: full (without it a step needs ~{need / gib:.1f} GiB computed, "
        f"more than 90 % of the {free / gib:.1f} GiB free; with it ~{est.total('full') / gib:.1f} GiB)"
    )
