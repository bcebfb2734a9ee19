"""The OSCAR DiT: Cosmos-Predict2.5's transformer plus a skeleton patch embedder (PE_s).

Why a subclass of :class:`~.cosmos_dit.CosmosDiT` (oscar's own Cosmos DiT, not diffusers'):

* The subclass keeps every state-dict key of the base model unchanged (``patch_embed.proj.weight``,
  ``transformer_blocks.0...``) and its config.json keys, so base Cosmos weights written by diffusers load
  strictly with no renaming, and ``from_config`` / ``save_pretrained`` write diffusers' folder layout. The only
  new key is ``skeleton_embed.proj.weight`` (PE_s); the only new setting ``skeleton_channels``.
* The skeleton tokens must be added right after PE_v and before the first block: the base forward takes
  ``added_tokens`` for exactly that, so this class only builds PE_s's tokens and passes them on.
* Nothing here imports diffusers: importing it costs seconds of CPU (every model it ships, transformers,
  ``torch._dynamo``). diffusers stays the reference in tests: tests/model/test_cosmos_dit.py checks the base
  against diffusers' ``CosmosTransformer3DModel`` and the shipped toy transformer against diffusers' class
  with the skeleton tokens added after its patch embedder; tests/model/test_model_transformer.py checks that a
  zero PE_s gives diffusers' output exactly.

Shapes (B batch, C latent channels, T latent frames, H x W latent pixels):
``hidden_states`` (B, C, T, H, W) noisy video latent; ``condition_mask``
(B, 1, T, H, W) 1 on conditioning frames; ``skeleton_latents`` (B, C_s, T, H,
W) the VAE latent of the skeleton video (C_s = ``skeleton_channels``, default
the latent channels); ``timestep`` (B,) or (B, 1, T, 1, 1) flow time sigma in
[0, 1] (Cosmos 2.5 feeds sigma itself, not 1000 sigma); output (B, C_out, T,
H, W) velocity.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from ._cosmos_layers import PatchEmbed
from .cosmos_dit import CosmosDiT, DiTOutput, check_cosmos_config
from .errors import CheckpointLayoutError, ModelInputError
from .weights import CONFIG_NAME, build_strict, cast_model, load_state_dict, read_config

__all__ = ["OscarTransformer3DModel", "SKELETON_EMBED_KEY"]

SKELETON_EMBED_KEY = "skeleton_embed.proj.weight"


class OscarTransformer3DModel(CosmosDiT):
    """:class:`~.cosmos_dit.CosmosDiT` (Cosmos' DiT) + PE_s, a zero-initialised skeleton patch embedder.

    All arguments are those of ``CosmosDiT`` (diffusers' ``CosmosTransformer3DModel``'s, kept as config),
    plus ``skeleton_channels``: channels of the skeleton latent fed to PE_s
    (None → ``out_channels``, the VAE latent channels: 16 for WAN 2.1).
    PE_s has the patch size of PE_v and no bias, and maps the skeleton latent
    to tokens summed with PE_v's video tokens before the first block.
    """

    config_class_name = "OscarTransformer3DModel"

    def __init__(self, *, skeleton_channels: int | None = None, **kwargs: Any) -> None:
        # kwargs: CosmosDiT's settings, recorded from its signature (see configured.py)
        super().__init__(**kwargs)
        hidden_size = self.config.num_attention_heads * self.config.attention_head_dim
        patch = tuple(self.config.patch_size)
        self.skeleton_embed = PatchEmbed(self.skeleton_in_channels, hidden_size, patch, bias=False)
        with torch.no_grad():
            self.skeleton_embed.proj.weight.zero_()

    # ------------------------------------------------------------------ building
    @classmethod
    def from_cosmos_base(
        cls, base, skeleton_channels: int | None = None, device=None, dtype: torch.dtype | None = None
    ) -> OscarTransformer3DModel:
        """Start fine-tuning from base Cosmos weights: the base loaded strictly plus a zero PE_s.

        base: a folder written by ``CosmosTransformer3DModel.save_pretrained``
            (diffusers' or :class:`~.cosmos_dit.CosmosDiT`'s; e.g. the ``transformer/`` folder of
            ``nvidia/Cosmos-Predict2.5-2B`` at revision ``diffusers/base/post-trained``), or such a model.
        The result equals the base model exactly (PE_s is zero), and no tensor
        is left on the meta device.
        """
        if isinstance(base, torch.nn.Module):
            config, state, source = dict(base.config), base.state_dict(), f"<{type(base).__name__} in memory>"
            state = {k: v.detach().to("cpu", copy=True) for k, v in state.items()}
            if SKELETON_EMBED_KEY in state:
                raise CheckpointLayoutError(
                    source,
                    "base model",
                    "a CosmosTransformer3DModel without PE_s",
                    f"a {type(base).__name__} (already has PE_s)",
                )
        else:
            config = read_config(base, ("CosmosTransformer3DModel",))
            check_cosmos_config(config, Path(base) / CONFIG_NAME)
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
        skeleton_latents: torch.Tensor | None = None,
        text_projected: bool = False,
    ) -> DiTOutput | tuple[torch.Tensor]:
        """Velocity of the noisy latent; arguments as :meth:`CosmosDiT.forward <.cosmos_dit.CosmosDiT.forward>`
        plus:

        skeleton_latents: (B, C_s, T, H, W) skeleton latent or None (no
            skeleton: exactly the base model). A zero latent also gives the
            base model's output, since PE_s has no bias.
        padding_mask: (1 or B, 1, H_px, W_px), 1 = padded pixel; None means
            "no padding" (zeros), which is what the Cosmos 2.5 pipeline passes.
        text_projected: the text context already went through
            :meth:`project_text` (a sampler does it once per chunk instead of
            once per step; the projection can then live on the CPU).
        """
        skeleton_tokens = None
        if skeleton_latents is not None:
            skeleton_tokens = self._skeleton_tokens(skeleton_latents, hidden_states.shape)
        return super().forward(
            hidden_states,
            timestep,
            encoder_hidden_states,
            block_controlnet_hidden_states=block_controlnet_hidden_states,
            attention_mask=attention_mask,
            fps=fps,
            condition_mask=condition_mask,
            padding_mask=padding_mask,
            return_dict=return_dict,
            text_projected=text_projected,
            added_tokens=skeleton_tokens,
        )

    def _skeleton_tokens(self, skeleton: torch.Tensor, video_shape) -> torch.Tensor:
        """PE_s tokens (B, T'H'W', D) of a skeleton latent of the video latent's batch, frames and size."""
        if len(video_shape) != 5:
            raise ModelInputError(f"hidden_states: expected (B, C, T, H, W), found shape {tuple(video_shape)}")
        b, _, t, h, w = video_shape
        want = (b, self.skeleton_in_channels, t, h, w)
        if tuple(skeleton.shape) != want:
            raise ModelInputError(
                f"skeleton_latents: expected shape {want} (batch, skeleton channels, and the video "
                f"latent's frames/size), found {tuple(skeleton.shape)}"
            )
        weight = self.skeleton_embed.proj.weight
        return self.skeleton_embed(skeleton.to(weight.dtype)).flatten(1, 3)
