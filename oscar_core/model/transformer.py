"""The OSCAR DiT: Cosmos-Predict2.5's transformer plus a skeleton patch embedder.

Why a subclass with its own ``forward`` (and not a hook or a wrapper):

* A subclass keeps every state-dict key of the base model unchanged
  (``patch_embed.proj.weight``, ``transformer_blocks.0...``), so base Cosmos
  weights load strictly with no renaming, and ``ConfigMixin``/``ModelMixin``
  keep ``save_pretrained``/``from_pretrained``/``from_config`` working with
  safetensors. The only new key is ``skeleton_embed.proj.weight`` (PE_s).
* The skeleton tokens must be added right after PE_v and before the first
  block. diffusers' forward gives no seam there; a forward hook on
  ``patch_embed`` would smuggle the skeleton in through module state. Our
  ``forward`` re-states the parent's steps in the same order, reusing the
  parent's sub-modules (patch embedder, RoPE, learnable positions, time
  embedding, blocks, output head) and adds two things: the PE_s sum and a
  torch-only padding-mask resize (no torchvision). A test checks it against
  the parent's own forward: with PE_s at zero the outputs are identical.

Shapes (B batch, C latent channels, T latent frames, H x W latent pixels):
``hidden_states`` (B, C, T, H, W) noisy video latent; ``condition_mask``
(B, 1, T, H, W) 1 on conditioning frames; ``skeleton_latents`` (B, C_s, T, H,
W) the VAE latent of the skeleton video (C_s = ``skeleton_channels``, default
the latent channels); ``timestep`` (B,) or (B, 1, T, 1, 1) flow time sigma in
[0, 1] (Cosmos 2.5 feeds sigma itself, not 1000 sigma); output (B, C_out, T,
H, W) velocity.
"""

from __future__ import annotations

import torch
from diffusers.configuration_utils import register_to_config
from diffusers.models.modeling_outputs import Transformer2DModelOutput
from diffusers.models.transformers.transformer_cosmos import CosmosPatchEmbed, CosmosTransformer3DModel

from ._resize import resize_padding_mask
from .errors import CheckpointLayoutError, ModelInputError
from .weights import build_strict, cast_model, load_state_dict, read_config

__all__ = ["OscarTransformer3DModel", "SKELETON_EMBED_KEY"]

SKELETON_EMBED_KEY = "skeleton_embed.proj.weight"


class OscarTransformer3DModel(CosmosTransformer3DModel):
    """``CosmosTransformer3DModel`` + PE_s, a zero-initialised skeleton patch embedder.

    All arguments are those of ``CosmosTransformer3DModel`` (kept as config),
    plus ``skeleton_channels``: channels of the skeleton latent fed to PE_s
    (None → ``out_channels``, the VAE latent channels: 16 for WAN 2.1).
    PE_s has the patch size of PE_v and no bias, and maps the skeleton latent
    to tokens summed with PE_v's video tokens before the first block.
    """

    _skip_layerwise_casting_patterns = ["patch_embed", "skeleton_embed", "final_layer", "norm"]
    # diffusers' from_pretrained refuses to load a class with _keep_in_fp32_modules unless `accelerate` is
    # installed; oscar does not need accelerate, so the list moves to `_oscar_keep_in_fp32_modules`, which
    # oscar's own loader (and `cast_model`) honours.
    _keep_in_fp32_modules = None
    _oscar_keep_in_fp32_modules = ["learnable_pos_embed"]

    @register_to_config
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
        skeleton_channels: int | None = None,
    ) -> None:
        super().__init__(
            in_channels=in_channels,
            out_channels=out_channels,
            num_attention_heads=num_attention_heads,
            attention_head_dim=attention_head_dim,
            num_layers=num_layers,
            mlp_ratio=mlp_ratio,
            text_embed_dim=text_embed_dim,
            adaln_lora_dim=adaln_lora_dim,
            max_size=max_size,
            patch_size=patch_size,
            rope_scale=rope_scale,
            concat_padding_mask=concat_padding_mask,
            extra_pos_embed_type=extra_pos_embed_type,
            use_crossattn_projection=use_crossattn_projection,
            crossattn_proj_in_channels=crossattn_proj_in_channels,
            encoder_hidden_states_channels=encoder_hidden_states_channels,
            controlnet_block_every_n=controlnet_block_every_n,
            img_context_dim_in=img_context_dim_in,
            img_context_num_tokens=img_context_num_tokens,
            img_context_dim_out=img_context_dim_out,
        )
        hidden_size = num_attention_heads * attention_head_dim
        self.skeleton_embed = CosmosPatchEmbed(self.skeleton_in_channels, hidden_size, tuple(patch_size), bias=False)
        with torch.no_grad():
            self.skeleton_embed.proj.weight.zero_()

    # ------------------------------------------------------------------ building
    @classmethod
    def load_strict(cls, folder, device=None, dtype: torch.dtype | None = None) -> OscarTransformer3DModel:
        """Load an OSCAR transformer folder (config.json + safetensors); every key must match, PE_s included."""
        config = read_config(folder, (cls.__name__,))
        model = build_strict(cls, config, load_state_dict(folder, device=device or "cpu"), folder)
        return cast_model(model, device, dtype)

    @classmethod
    def from_cosmos_base(
        cls, base, skeleton_channels: int | None = None, device=None, dtype: torch.dtype | None = None
    ) -> OscarTransformer3DModel:
        """Start fine-tuning from base Cosmos weights: the base loaded strictly plus a zero PE_s.

        base: a folder written by ``CosmosTransformer3DModel.save_pretrained``
            (e.g. the ``transformer/`` folder of ``nvidia/Cosmos-Predict2.5-2B``
            at revision ``diffusers/base/post-trained``), or such a model.
        The result equals the base model exactly (PE_s is zero), and no tensor
        is left on the meta device.
        """
        if isinstance(base, CosmosTransformer3DModel):
            config, state, source = dict(base.config), base.state_dict(), f"<{type(base).__name__} in memory>"
            state = {k: v.detach().to("cpu", copy=True) for k, v in state.items()}
            if isinstance(base, cls):
                raise CheckpointLayoutError(
                    source,
                    "base model",
                    "a CosmosTransformer3DModel without PE_s",
                    "an OscarTransformer3DModel (already has PE_s)",
                )
        else:
            config = read_config(base, ("CosmosTransformer3DModel",))
            state, source = load_state_dict(base), base
        config = {k: v for k, v in config.items() if not k.startswith("_")}
        config["skeleton_channels"] = skeleton_channels
        model = build_strict(cls, config, state, source, zero_missing=(SKELETON_EMBED_KEY,))
        return cast_model(model, device, dtype)

    # ------------------------------------------------------------------ config helpers
    @property
    def skeleton_in_channels(self) -> int:
        """Channels PE_s expects: ``skeleton_channels`` or, when None, ``out_channels``."""
        c = self.config.skeleton_channels
        return int(self.config.out_channels if c is None else c)

    @property
    def latent_channels(self) -> int:
        """Channels of the video latent (``out_channels``, 16 for WAN 2.1; ``in_channels`` adds the condition mask)."""
        return int(self.config.out_channels)

    @property
    def text_dim(self) -> int:
        """Last dimension of the prompt embedding this model takes (before its cross-attention projection)."""
        cfg = self.config
        return int(cfg.crossattn_proj_in_channels if cfg.use_crossattn_projection else cfg.text_embed_dim)

    # ------------------------------------------------------------------ forward
    def forward(
        self,
        hidden_states: torch.Tensor,
        timestep: torch.Tensor,
        encoder_hidden_states: torch.Tensor | tuple,
        block_controlnet_hidden_states: list[torch.Tensor] | None = None,
        attention_mask: torch.Tensor | None = None,
        fps: int | None = None,
        condition_mask: torch.Tensor | None = None,
        padding_mask: torch.Tensor | None = None,
        return_dict: bool = True,
        skeleton_latents: torch.Tensor | None = None,
        text_projected: bool = False,
    ) -> tuple[torch.Tensor] | Transformer2DModelOutput:
        """Velocity of the noisy latent; arguments as ``CosmosTransformer3DModel.forward`` plus:

        skeleton_latents: (B, C_s, T, H, W) skeleton latent or None (no
            skeleton: exactly the base model). A zero latent also gives the
            base model's output, since PE_s has no bias.
        padding_mask: (1 or B, 1, H_px, W_px), 1 = padded pixel; None means
            "no padding" (zeros), which is what the Cosmos 2.5 pipeline passes.
        text_projected: the text context already went through
            :meth:`project_text` (a sampler does it once per chunk instead of
            once per step; the projection can then live on the CPU).
        """
        cfg = self.config
        if hidden_states.ndim != 5:
            raise ModelInputError(f"hidden_states: expected (B, C, T, H, W), found shape {tuple(hidden_states.shape)}")
        batch, _, frames, height, width = hidden_states.shape
        p_t, p_h, p_w = cfg.patch_size
        if frames % p_t or height % p_h or width % p_w:
            raise ModelInputError(
                f"hidden_states: expected T, H, W divisible by the patch size {tuple(cfg.patch_size)}, "
                f"found {(frames, height, width)}"
            )

        # 1. extra input channels: condition mask, then the resized padding mask
        x = hidden_states if condition_mask is None else torch.cat([hidden_states, condition_mask], dim=1)
        if cfg.concat_padding_mask:
            x = torch.cat([x, self._padding_channel(padding_mask, x, batch, frames)], dim=1)
        if attention_mask is not None:
            attention_mask = attention_mask.unsqueeze(1).unsqueeze(1)  # (B, S) -> (B, 1, 1, S)

        want = self.patch_embed.proj.in_features // (p_t * p_h * p_w)
        if x.shape[1] != want:
            raise ModelInputError(
                f"hidden_states: expected {want} input channels to the patch embedder (latent + "
                f"condition mask{' + padding mask' if cfg.concat_padding_mask else ''}), found "
                f"{x.shape[1]}; pass condition_mask when the model has an extra mask channel"
            )

        # 2. positions (they depend on the shape of x only)
        rotary = self.rope(x, fps=fps)
        extra_pos = self.learnable_pos_embed(x) if cfg.extra_pos_embed_type else None

        # 3. tokens: PE_v(video) + PE_s(skeleton), (B, T'H'W', D)
        tokens = self.patch_embed(x).flatten(1, 3)
        if skeleton_latents is not None:
            tokens = tokens + self._skeleton_tokens(skeleton_latents, hidden_states.shape, tokens.dtype)

        # 4. time embedding, per sample (B,) or per latent frame (B, 1, T, 1, 1)
        temb, embedded_t = self._time_embedding(tokens, timestep, batch, frames // p_t, height // p_h, width // p_w)

        # 5. text (and optional image) context
        text_ctx, img_ctx = (
            encoder_hidden_states if isinstance(encoder_hidden_states, tuple) else (encoder_hidden_states, None)
        )
        if not text_projected:
            text_ctx = self.project_text(text_ctx)
        if img_ctx is not None and cfg.img_context_dim_in:
            img_ctx = self.img_context_proj(img_ctx)
        context = (text_ctx, img_ctx) if isinstance(encoder_hidden_states, tuple) else text_ctx

        # 6. blocks (+ optional controlnet residuals every n blocks)
        residuals = {}
        if block_controlnet_hidden_states is not None:
            every = cfg.controlnet_block_every_n
            residuals = {
                b: block_controlnet_hidden_states[i]
                for i, b in enumerate(range(0, len(self.transformer_blocks), every))
            }
        for index, block in enumerate(self.transformer_blocks):
            args = (tokens, context, embedded_t, temb, rotary, extra_pos, attention_mask, residuals.get(index))
            if torch.is_grad_enabled() and self.gradient_checkpointing:
                tokens = self._gradient_checkpointing_func(block, *args)
            else:
                tokens = block(*args)

        # 7. output head and unpatchify
        out = self.proj_out(self.norm_out(tokens, embedded_t, temb))
        out = self._unpatchify(out, batch, frames // p_t, height // p_h, width // p_w)
        return Transformer2DModelOutput(sample=out) if return_dict else (out,)

    def project_text(self, text: torch.Tensor) -> torch.Tensor:
        """(B, L, text_dim) prompt embedding → (B, L, text_embed_dim) cross-attention context.

        Runs wherever ``crossattn_proj`` lives (see ``OscarWorldModel``'s
        ``offload_text``); identity when the model has no text projection.
        """
        if not self.config.use_crossattn_projection:
            return text
        weight = self.crossattn_proj[0].weight
        return self.crossattn_proj(text.to(weight.device, weight.dtype))

    # ------------------------------------------------------------------ pieces
    def _padding_channel(self, padding_mask, x, batch: int, frames: int) -> torch.Tensor:
        """(B, 1, T, H, W) padding-mask channel, nearest-resized like diffusers does with torchvision."""
        height, width = x.shape[-2:]
        if padding_mask is None:
            return x.new_zeros(batch, 1, frames, height, width)
        if padding_mask.ndim != 4 or padding_mask.shape[1] != 1 or padding_mask.shape[0] not in (1, batch):
            raise ModelInputError(
                f"padding_mask: expected (1 or {batch}, 1, H, W), found shape {tuple(padding_mask.shape)}"
            )
        mask = resize_padding_mask(padding_mask, (height, width)).to(x.dtype)
        return mask.unsqueeze(2).expand(batch, 1, frames, height, width)

    def _skeleton_tokens(self, skeleton: torch.Tensor, video_shape, dtype) -> torch.Tensor:
        """PE_s tokens (B, T'H'W', D) of a skeleton latent of the video latent's batch, frames and size."""
        b, _, t, h, w = video_shape
        want = (b, self.skeleton_in_channels, t, h, w)
        if tuple(skeleton.shape) != want:
            raise ModelInputError(
                f"skeleton_latents: expected shape {want} (batch, skeleton channels, and the video "
                f"latent's frames/size), found {tuple(skeleton.shape)}"
            )
        weight = self.skeleton_embed.proj.weight
        return self.skeleton_embed(skeleton.to(weight.dtype)).flatten(1, 3).to(dtype)

    def _time_embedding(self, tokens, timestep: torch.Tensor, batch: int, t: int, h: int, w: int):
        if timestep.ndim == 1:
            return self.time_embed(tokens, timestep)
        if timestep.ndim == 5:
            if tuple(timestep.shape) != (batch, 1, t, 1, 1):
                raise ModelInputError(
                    f"timestep: expected (B,) or (B, 1, T, 1, 1) = {(batch, 1, t, 1, 1)}, found {tuple(timestep.shape)}"
                )
            temb, embedded = self.time_embed(tokens, timestep.flatten())
            # per latent frame -> per token (valid because the temporal patch size is 1 for Cosmos)
            return tuple(e.view(batch, t, 1, 1, -1).expand(-1, -1, h, w, -1).flatten(1, 3) for e in (temb, embedded))
        raise ModelInputError(f"timestep: expected (B,) or (B, 1, T, 1, 1), found shape {tuple(timestep.shape)}")

    def _unpatchify(self, out: torch.Tensor, batch: int, t: int, h: int, w: int) -> torch.Tensor:
        """(B, T'H'W', p_h p_w p_t C) → (B, C, T' p_t, H' p_h, W' p_w).

        The projection's channel layout is (p_h, p_w, p_t, C), as in diffusers.
        """
        p_t, p_h, p_w = self.config.patch_size
        out = out.reshape(batch, t, h, w, p_h, p_w, p_t, -1)
        out = out.permute(0, 7, 1, 6, 2, 4, 3, 5)  # B, C, T', p_t, H', p_h, W', p_w
        return out.reshape(batch, out.shape[1], t * p_t, h * p_h, w * p_w)
