"""Tiny configurations of the real classes, for tests, examples and benchmarks on a CPU.

They use the same classes as the 2B model (``OscarTransformer3DModel``,
:class:`~.wan_vae.WanVAE`) with a few layers and small widths, so every code path
(RoPE, learnable positions, cross-attention projection, padding mask,
causal VAE with 4x time / 8x space compression) runs in milliseconds.
Weights are random (seeded): outputs mean nothing, but they are exact
functions of the seed, which is what tests need.
"""

from __future__ import annotations

import torch

__all__ = [
    "TINY_TRANSFORMER_CONFIG",
    "TINY_VAE_CONFIG",
    "COSMOS_2B_TRANSFORMER_CONFIG",
    "build_random_2b",
    "build_tiny_transformer",
    "build_tiny_vae",
]

#: Tiny DiT: hidden 64 (2 heads x 32), 2 blocks, 16 latent channels + condition mask, text dim 48 -> 32.
TINY_TRANSFORMER_CONFIG = dict(
    in_channels=17,
    out_channels=16,
    num_attention_heads=2,
    attention_head_dim=32,
    num_layers=2,
    mlp_ratio=2.0,
    text_embed_dim=32,
    adaln_lora_dim=16,
    max_size=(32, 64, 64),
    patch_size=(1, 2, 2),
    rope_scale=(1.0, 1.0, 1.0),
    concat_padding_mask=True,
    extra_pos_embed_type="learnable",
    use_crossattn_projection=True,
    crossattn_proj_in_channels=48,
    encoder_hidden_states_channels=32,
)

#: Tiny WAN 2.1 VAE: z = 16, 4x time and 8x space compression like the real one, base width 8.
TINY_VAE_CONFIG = dict(
    base_dim=8,
    z_dim=16,
    dim_mult=[1, 2, 2, 2],
    num_res_blocks=1,
    attn_scales=[],
    temperal_downsample=[False, True, True],
)

#: Cosmos-Predict2.5-2B transformer exactly as diffusers' conversion script builds it
#: (``scripts/convert_cosmos_to_diffusers.py``, entry "Cosmos-2.5-Predict-Base-2B"): 28 blocks, 16 heads x 128,
#: patch (1, 2, 2), 16 + 1 condition-mask input channels + padding mask, text 100352 -> 1024, RoPE scale
#: (1, 3, 3) and no learnable positional embedding (the native config says "learnable" but ships no weights).
COSMOS_2B_TRANSFORMER_CONFIG = dict(
    in_channels=17,
    out_channels=16,
    num_attention_heads=16,
    attention_head_dim=128,
    num_layers=28,
    mlp_ratio=4.0,
    text_embed_dim=1024,
    adaln_lora_dim=256,
    max_size=(128, 240, 240),
    patch_size=(1, 2, 2),
    rope_scale=(1.0, 3.0, 3.0),
    concat_padding_mask=True,
    extra_pos_embed_type=None,
    use_crossattn_projection=True,
    crossattn_proj_in_channels=100352,
    encoder_hidden_states_channels=1024,
)


def randomise(model: torch.nn.Module, seed: int, scale: float) -> None:
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.copy_(torch.randn(p.shape, generator=g) * scale)


def build_tiny_transformer(seed: int = 0, skeleton_scale: float | None = None, **overrides):
    """A tiny ``OscarTransformer3DModel`` with seeded weights.

    Every weight is redrawn (diffusers zero-initialises some output layers,
    which would make tests blind). PE_s stays zero unless ``skeleton_scale``
    is given (then it is drawn too, with that standard deviation).
    """
    from .transformer import OscarTransformer3DModel

    model = OscarTransformer3DModel(**{**TINY_TRANSFORMER_CONFIG, **overrides})
    randomise(model, seed, 0.05)
    with torch.no_grad():
        w = model.skeleton_embed.proj.weight
        if skeleton_scale is None:
            w.zero_()
        else:
            w.copy_(torch.randn(w.shape, generator=torch.Generator().manual_seed(seed + 1)) * skeleton_scale)
    return model.eval()


def build_tiny_vae(seed: int = 0, **overrides):
    """A tiny :class:`~.wan_vae.WanVAE` with seeded default-initialised weights (the same tensors as diffusers'
    ``AutoencoderKLWan`` draws for the seed: tests/model/test_wan_vae.py)."""
    from .wan_vae import WanVAE

    torch.manual_seed(seed)  # torch's default init draws from the global generator
    return WanVAE(**{**TINY_VAE_CONFIG, **overrides}).eval()


def build_random_2b(device="cpu", dtype: torch.dtype = torch.bfloat16, seed: int = 0):
    """(transformer, vae): the 2B DiT (:data:`COSMOS_2B_TRANSFORMER_CONFIG`) and the WAN 2.1 VAE (:class:`WanVAE`'s
    defaults, diffusers' ``AutoencoderKLWan``'s) with random default-initialised weights, in eval mode, for speed and memory
    measurements. Both are initialised directly in ``dtype`` on ``device`` (no float32 copy of 2 B parameters on
    the host; a minute on a CPU, seconds on a GPU)."""
    from .transformer import OscarTransformer3DModel
    from .wan_vae import WanVAE

    torch.manual_seed(seed)
    default = torch.get_default_dtype()
    torch.set_default_dtype(dtype)
    try:
        with torch.device(device):
            return OscarTransformer3DModel(**COSMOS_2B_TRANSFORMER_CONFIG).eval(), WanVAE().eval()
    finally:
        torch.set_default_dtype(default)
