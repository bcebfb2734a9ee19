"""Cosmos-Predict2.5's video DiT in plain torch: diffusers' state-dict keys and config.json keys, no diffusers.

:class:`CosmosDiT` computes what diffusers 0.42.1's ``CosmosTransformer3DModel`` computes (tests/model/
test_cosmos_dit.py compares the two on random weights), with the same parameter names, the same constructor
settings and ``_class_name`` in config.json, so a folder written by either loads in the other. oscar runs its
own copy because importing diffusers costs seconds of CPU (it imports every model it ships, transformers and
``torch._dynamo``); this module imports torch only.

One forward pass, for a latent of B clips, C channels, T x H x W latent pixels and patch (p_t, p_h, p_w):

1. input channels: the latent, the condition mask (when given), the padding mask resized to H x W (when the
   config says ``concat_padding_mask``);
2. tokens: one linear map per patch, N = T' H' W' tokens of D = heads x head_dim (T' = T / p_t, ...);
3. positions: 3-D rotary angles (``rope_scale``) for the self-attention, and, with ``extra_pos_embed_type:
   learnable``, learnt per-axis embeddings added before every block;
4. time: a sinusoid of the flow time sigma (per clip, or per latent frame), an MLP of it and its RMS norm,
   which drive every AdaLN-LoRA modulation;
5. text: the prompt embedding, through ``crossattn_proj`` (Linear + GELU) when ``use_crossattn_projection``;
6. ``num_layers`` blocks (self-attention, cross-attention, MLP; ControlNet residuals every
   ``controlnet_block_every_n`` blocks when given);
7. a modulated output norm, a linear head and the inverse of the patching.

Settings oscar does not implement are refused by :func:`check_cosmos_config` (image context,
``img_context_dim_in``, from Cosmos-Transfer; positional embeddings other than ``learnable``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import torch
from torch import nn

from ._cosmos_layers import (
    AdaLNModulation,
    LearnablePositions,
    PatchEmbed,
    RotaryPositions,
    TimestepEmbedding,
    TransformerBlock,
)
from ._resize import resize_padding_mask
from .configured import ConfiguredModule
from .errors import CheckpointLayoutError, ModelInputError
from .weights import CONFIG_NAME, build_strict, cast_model, load_state_dict, read_config

__all__ = ["CosmosDiT", "DiTOutput", "check_cosmos_config"]


class DiTOutput(NamedTuple):
    """A forward's result: ``out.sample`` or ``out[0]``, (B, C_out, T, H, W)."""

    sample: torch.Tensor


def _is_int(value, low: int = 1) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= low


def _triple(value, kind) -> bool:
    return isinstance(value, list | tuple) and len(value) == 3 and all(kind(v) for v in value)


def _number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and v > 0


#: setting → (test of an accepted value, what is accepted); a setting left out of a mapping keeps its default
_ACCEPTED = {
    "img_context_dim_in": (lambda v: v in (None, 0), "null (oscar's DiT has no image-context cross-attention)"),
    "extra_pos_embed_type": (lambda v: v in (None, "learnable"), "null or 'learnable'"),
    "attention_head_dim": (lambda v: _is_int(v, 12) and v % 2 == 0, "an even integer >= 12 (3-D RoPE splits it)"),
    "num_attention_heads": (_is_int, "a positive integer"),
    "num_layers": (lambda v: _is_int(v, 0), "a non-negative integer"),
    "adaln_lora_dim": (_is_int, "a positive integer (AdaLN-LoRA rank)"),
    "patch_size": (lambda v: _triple(v, _is_int), "3 positive integers (t, h, w)"),
    "max_size": (lambda v: _triple(v, _is_int), "3 positive integers (t, h, w)"),
    "rope_scale": (lambda v: _triple(v, _number), "3 positive numbers (t, h, w)"),
    "controlnet_block_every_n": (lambda v: v is None or _is_int(v), "null or a positive integer"),
}


def check_cosmos_config(config: Mapping, source=CONFIG_NAME) -> None:
    """Refuse settings :class:`CosmosDiT` does not implement, naming ``source`` (a config.json) and the field."""
    for key, (accepted, expected) in _ACCEPTED.items():
        if key in config and not accepted(config[key]):
            raise CheckpointLayoutError(source, key, expected, repr(config[key]))


class CosmosDiT(ConfiguredModule):
    """Cosmos-Predict2.5's DiT; settings (kept as ``config``) and parameter names as diffusers'
    ``CosmosTransformer3DModel``.

    in_channels: latent channels + 1 when a condition mask is concatenated (the padding mask adds one more
    when ``concat_padding_mask``); out_channels: latent channels; hidden size D = num_attention_heads x
    attention_head_dim; text_embed_dim: the cross-attention context's width (after ``crossattn_proj``, which
    maps ``crossattn_proj_in_channels`` → ``encoder_hidden_states_channels`` when
    ``use_crossattn_projection``); max_size: the largest latent (T, H, W) the positions cover.
    ``img_context_num_tokens`` / ``img_context_dim_out`` are kept for config compatibility and unused.
    """

    config_class_name = "CosmosTransformer3DModel"
    _keep_in_fp32_modules = ("learnable_pos_embed",)

    def __init__(
        self,
        in_channels: int = 16,
        out_channels: int = 16,
        num_attention_heads: int = 32,
        attention_head_dim: int = 128,
        num_layers: int = 28,
        mlp_ratio: float = 4.0,
        text_embed_dim: int = 1024,
        adaln_lora_dim: int = 256,
        max_size: tuple[int, int, int] = (128, 240, 240),
        patch_size: tuple[int, int, int] = (1, 2, 2),
        rope_scale: tuple[float, float, float] = (2.0, 1.0, 1.0),
        concat_padding_mask: bool = True,
        extra_pos_embed_type: str | None = "learnable",
        use_crossattn_projection: bool = False,
        crossattn_proj_in_channels: int = 1024,
        encoder_hidden_states_channels: int = 1024,
        controlnet_block_every_n: int | None = None,
        img_context_dim_in: int | None = None,
        img_context_num_tokens: int = 256,
        img_context_dim_out: int = 2048,
    ) -> None:
        super().__init__()
        check_cosmos_config(self.config)
        heads, head_dim = num_attention_heads, attention_head_dim
        hidden = heads * head_dim
        patch = tuple(int(p) for p in patch_size)
        max_grid = tuple(int(s) // p for s, p in zip(max_size, patch))
        # construction order as in diffusers: a seeded default init draws the same numbers
        self.patch_embed = PatchEmbed(in_channels + int(bool(concat_padding_mask)), hidden, patch)
        self.rope = RotaryPositions(head_dim, max_grid, tuple(rope_scale))
        self.learnable_pos_embed = LearnablePositions(hidden, max_grid) if extra_pos_embed_type else None
        self.time_embed = TimestepEmbedding(hidden)
        self.transformer_blocks = nn.ModuleList(
            TransformerBlock(heads, head_dim, text_embed_dim, mlp_ratio, adaln_lora_dim) for _ in range(num_layers)
        )
        self.norm_out = AdaLNModulation(hidden, adaln_lora_dim, chunks=2)
        self.proj_out = nn.Linear(hidden, math.prod(patch) * out_channels, bias=False)
        if use_crossattn_projection:
            self.crossattn_proj = nn.Sequential(
                nn.Linear(crossattn_proj_in_channels, encoder_hidden_states_channels), nn.GELU()
            )
        self.gradient_checkpointing = False

    # ------------------------------------------------------------------ building and facts
    @classmethod
    def from_config(cls, config: Mapping, source: str | Path = CONFIG_NAME):
        """Build from a config mapping; unimplemented settings refused first, naming ``source``."""
        check_cosmos_config(config, source)
        return super().from_config(config, source)

    @classmethod
    def load_strict(cls, folder, device=None, dtype: torch.dtype | None = None):
        """Load a model folder (config.json + safetensors) written for this class; every key must match.

        config.json's ``_class_name`` must be this class's ``config_class_name``; settings are checked before
        any weight is read. dtype: cast to it, the learnt positions kept in float32.
        """
        config = read_config(folder, (cls.config_class_name,))
        check_cosmos_config(config, Path(folder) / CONFIG_NAME)
        model = build_strict(cls, config, load_state_dict(folder, device=device or "cpu"), folder)
        return cast_model(model, device, dtype)

    @classmethod
    def from_pretrained(cls, folder, device=None, dtype: torch.dtype | None = None, torch_dtype=None):
        """:meth:`load_strict` under diffusers' name (a local folder only; ``torch_dtype`` as diffusers spells it)."""
        return cls.load_strict(folder, device=device, dtype=dtype or torch_dtype)

    @property
    def dtype(self) -> torch.dtype:
        """The compute dtype: the patch embedder's (the learnt positions may be kept in float32)."""
        return self.patch_embed.proj.weight.dtype

    @property
    def device(self) -> torch.device:
        return self.patch_embed.proj.weight.device

    @property
    def latent_channels(self) -> int:
        """Channels of the video latent (``out_channels``, 16 for WAN 2.1; ``in_channels`` adds the condition mask)."""
        return int(self.config.out_channels)

    @property
    def text_dim(self) -> int:
        """Last dimension of the prompt embedding this model takes (before its cross-attention projection)."""
        cfg = self.config
        return int(cfg.crossattn_proj_in_channels if cfg.use_crossattn_projection else cfg.text_embed_dim)

    def enable_gradient_checkpointing(self) -> None:
        """Recompute each block in the backward pass instead of keeping its activations (training only)."""
        self.gradient_checkpointing = True

    def disable_gradient_checkpointing(self) -> None:
        self.gradient_checkpointing = False

    # ------------------------------------------------------------------ forward
    def forward(
        self,
        hidden_states: torch.Tensor,
        timestep: torch.Tensor,
        encoder_hidden_states: torch.Tensor,
        block_controlnet_hidden_states: list[torch.Tensor] | None = None,
        attention_mask: torch.Tensor | None = None,
        fps: float | None = None,
        condition_mask: torch.Tensor | None = None,
        padding_mask: torch.Tensor | None = None,
        return_dict: bool = True,
        text_projected: bool = False,
        added_tokens: torch.Tensor | None = None,
    ) -> DiTOutput | tuple[torch.Tensor]:
        """Velocity of a noisy latent.

        hidden_states: (B, C, T, H, W) noisy latent; timestep: (B,) flow time sigma in [0, 1], or
        (B, 1, T, 1, 1) one per latent frame (temporal patch 1 only); encoder_hidden_states: (B, L, text_dim)
        prompt embedding; block_controlnet_hidden_states: (B, N, D) residuals added after blocks 0, n, 2n, ...
        (n = ``controlnet_block_every_n``); attention_mask: (B, L) for the text keys (bool: True = attend,
        float: added to the logits); fps: frame rate of the clip (scales the temporal RoPE; None = index);
        condition_mask: (B, 1, T, H, W) 1 on conditioning frames; padding_mask: (1 or B, 1, H_px, W_px) 1 =
        padded pixel, None = no padding; text_projected: the context already went through
        :meth:`project_text`; added_tokens: (B, N, D) summed with the patch tokens before the first block.
        Returns ``DiTOutput(sample)`` or, with ``return_dict=False``, ``(sample,)``: (B, C_out, T, H, W).
        """
        batch, grid = self._latent_grid(hidden_states)
        x = self._input_channels(hidden_states, condition_mask, padding_mask)
        tokens = self.patch_embed(x).flatten(1, 3)
        if added_tokens is not None:
            tokens = tokens + added_tokens.to(tokens.dtype)
        temb, embedded = self._time_embedding(tokens, timestep, batch, *grid)
        context = encoder_hidden_states if text_projected else self.project_text(encoder_hidden_states)
        shared = (
            context,
            embedded,
            temb,
            self.rope(grid, x.device, fps),
            None if self.learnable_pos_embed is None else self.learnable_pos_embed(grid, x.dtype),
            None if attention_mask is None else attention_mask[:, None, None, :],
        )
        tokens = self._run_blocks(tokens, shared, block_controlnet_hidden_states)
        out = self.proj_out(self.norm_out(tokens, embedded, temb)[0])
        out = self._unpatchify(out, batch, *grid)
        return DiTOutput(out) if return_dict else (out,)

    def project_text(self, text: torch.Tensor) -> torch.Tensor:
        """(B, L, text_dim) prompt embedding → (B, L, text_embed_dim) cross-attention context.

        Runs wherever ``crossattn_proj`` lives (see ``OscarWorldModel``'s ``offload_text``); identity when the
        model has no text projection.
        """
        if not isinstance(text, torch.Tensor):
            raise ModelInputError(
                f"encoder_hidden_states: expected a (B, L, {self.text_dim}) tensor (oscar's DiT has no image "
                f"context), found {type(text).__name__}"
            )
        if not self.config.use_crossattn_projection:
            return text
        weight = self.crossattn_proj[0].weight
        return self.crossattn_proj(text.to(weight.device, weight.dtype))

    # ------------------------------------------------------------------ steps
    def _latent_grid(self, hidden_states: torch.Tensor) -> tuple[int, tuple[int, int, int]]:
        """(B, (T', H', W')) of a (B, C, T, H, W) latent; refuses sizes the patch does not divide."""
        if hidden_states.ndim != 5:
            raise ModelInputError(f"hidden_states: expected (B, C, T, H, W), found shape {tuple(hidden_states.shape)}")
        batch, _, frames, height, width = hidden_states.shape
        p_t, p_h, p_w = self.patch_embed.patch_size
        if frames % p_t or height % p_h or width % p_w:
            raise ModelInputError(
                f"hidden_states: expected T, H, W divisible by the patch size {(p_t, p_h, p_w)}, "
                f"found {(frames, height, width)}"
            )
        return batch, (frames // p_t, height // p_h, width // p_w)

    def _input_channels(self, hidden_states, condition_mask, padding_mask) -> torch.Tensor:
        """(B, C_in, T, H, W): the latent, the condition mask, the padding-mask channel, as the config says."""
        x = hidden_states if condition_mask is None else torch.cat([hidden_states, condition_mask], dim=1)
        if self.config.concat_padding_mask:
            x = torch.cat([x, self._padding_channel(padding_mask, x)], dim=1)
        p_t, p_h, p_w = self.patch_embed.patch_size
        want = self.patch_embed.proj.in_features // (p_t * p_h * p_w)
        if x.shape[1] != want:
            raise ModelInputError(
                f"hidden_states: expected {want} input channels to the patch embedder (latent + condition "
                f"mask{' + padding mask' if self.config.concat_padding_mask else ''}), found {x.shape[1]}; pass "
                "condition_mask when the model has an extra mask channel"
            )
        return x

    def _padding_channel(self, padding_mask, x: torch.Tensor) -> torch.Tensor:
        """(B, 1, T, H, W) padding-mask channel, nearest-resized as torchvision does (:mod:`._resize`)."""
        batch, _, frames, height, width = x.shape
        if padding_mask is None:
            return x.new_zeros(batch, 1, frames, height, width)
        if padding_mask.ndim != 4 or padding_mask.shape[1] != 1 or padding_mask.shape[0] not in (1, batch):
            raise ModelInputError(
                f"padding_mask: expected (1 or {batch}, 1, H, W), found shape {tuple(padding_mask.shape)}"
            )
        mask = resize_padding_mask(padding_mask, (height, width)).to(x.dtype)
        return mask.unsqueeze(2).expand(batch, 1, frames, height, width)

    def _time_embedding(self, tokens, timestep: torch.Tensor, batch: int, t: int, h: int, w: int):
        """(temb, embedded): (B, 3D), (B, D) for a (B,) timestep; (B, N, 3D), (B, N, D) for (B, 1, T, 1, 1)."""
        if timestep.ndim == 1:
            return self.time_embed(timestep, tokens.dtype)
        if timestep.ndim == 5 and self.patch_embed.patch_size[0] == 1:
            if tuple(timestep.shape) != (batch, 1, t, 1, 1):
                raise ModelInputError(
                    f"timestep: expected (B,) or (B, 1, T, 1, 1) = {(batch, 1, t, 1, 1)}, found {tuple(timestep.shape)}"
                )
            temb, embedded = self.time_embed(timestep.flatten(), tokens.dtype)
            # one value per latent frame, repeated over the frame's tokens (token order is t, h, w)
            return tuple(e.view(batch, t, 1, 1, -1).expand(-1, -1, h, w, -1).flatten(1, 3) for e in (temb, embedded))
        raise ModelInputError(
            f"timestep: expected (B,) or, with temporal patch 1, (B, 1, T, 1, 1), found shape {tuple(timestep.shape)}"
        )

    def _controlnet_residuals(self, residuals) -> dict[int, torch.Tensor]:
        """Block index → residual: the i-th residual goes after block i x ``controlnet_block_every_n``."""
        if residuals is None:
            return {}
        every = self.config.controlnet_block_every_n
        targets = range(0, len(self.transformer_blocks), every or 1)
        if not every or len(residuals) < len(targets):
            raise ModelInputError(
                f"block_controlnet_hidden_states: expected {len(targets)} residuals (config.json "
                f"controlnet_block_every_n = {every!r}), found {len(residuals)}"
            )
        return {block: residuals[i] for i, block in enumerate(targets)}

    def _run_blocks(self, tokens: torch.Tensor, shared: tuple, controlnet) -> torch.Tensor:
        """The blocks in order; ``shared`` = (context, embedded, temb, rotary, extra_pos, mask)."""
        residuals = self._controlnet_residuals(controlnet)
        checkpointed = self.gradient_checkpointing and torch.is_grad_enabled()
        for index, block in enumerate(self.transformer_blocks):
            args = (tokens, *shared, residuals.get(index))
            if checkpointed:
                from torch.utils.checkpoint import checkpoint

                tokens = checkpoint(block, *args, use_reentrant=False)
            else:
                tokens = block(*args)
        return tokens

    def _unpatchify(self, out: torch.Tensor, batch: int, t: int, h: int, w: int) -> torch.Tensor:
        """(B, N, p_h p_w p_t C) → (B, C, T' p_t, H' p_h, W' p_w); the head's channels are laid out
        (p_h, p_w, p_t, C), as in Cosmos checkpoints."""
        p_t, p_h, p_w = self.patch_embed.patch_size
        out = out.reshape(batch, t, h, w, p_h, p_w, p_t, -1)
        out = out.permute(0, 7, 1, 6, 2, 4, 3, 5)  # B, C, T', p_t, H', p_h, W', p_w
        return out.reshape(batch, out.shape[1], t * p_t, h * p_h, w * p_w)
