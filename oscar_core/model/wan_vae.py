"""The Wan video VAE (Wan 2.1, and Wan 2.2's residual variant), in torch alone, computing what diffusers' does.

Same state-dict keys and shapes and the same ``config.json`` settings as diffusers' ``AutoencoderKLWan`` (0.42), so a
``vae/`` folder written by either library loads in both (:class:`WanVAE`, ``config_class_name = "AutoencoderKLWan"``).
Tests compare it with diffusers' class on shared random weights (tests/model/test_wan_vae.py).

Shapes: pixels (B, C_in, T, H, W) in [-1, 1] with T = 1 + 4k; latents (B, z_dim, 1 + k, H / s, W / s) with
s = 2^(len(dim_mult) - 1); each ``True`` in ``temperal_downsample`` halves time (two of them: 4x).

Architecture (widths d_i = base_dim × (1, *dim_mult)):

* **Causal 3-D convolutions** (:class:`CausalConv3d`): a 3x3x3 kernel padded by 1 in space and by 2 frames of
  zeros *before* the clip in time, so output frame t sees input frames t-2..t only. 1x1x1 kernels need no padding.
* **Residual block** (:class:`ResidualBlock`): RMS norm, SiLU, causal conv, RMS norm, SiLU, dropout, causal conv,
  plus the input (through a 1x1x1 conv when the width changes).
* **RMS norm** (:class:`RMSNorm`): each pixel's channel vector divided by its L2 norm (at least 1e-12), times sqrt(C)
  and a learnt per-channel gain (float32 arithmetic for half-precision inputs). On the CPU without autograd the norm
  of large float32 activations is summed from the squares in the order torch's own norm adds them, bit-identical
  and about 4x faster (:func:`~._wan_vae_layers.channel_norm_by_sums`).
* **Mid block** (:class:`MidBlock`): residual block, single-head self-attention over the pixels of each frame
  (:class:`FrameAttention`; 1x1 conv to q, k, v; no mixing across frames), residual block.
* **Resampling** (:class:`Resample`): down = zero pad right/bottom, 3x3 conv at stride 2 per frame; in time a
  (3, 1, 1) conv at stride 2 over the previous chunk's last frame and this chunk's frames (the clip's first frame
  passes through). Up = nearest-exact x2 in space and a 3x3 conv per frame (Wan 2.1 halves the width there); in
  time a causal (3, 1, 1) conv to 2C channels whose halves become two output frames (the first latent frame gives
  one frame and does not enter that conv).
* **Wan 2.2 (``is_residual=True``)**: each down stage adds a parameter-free shortcut from its input (space and time
  folded into channels, then averaged in groups: :func:`fold_down`); each up stage one from its input (channels
  repeated and unfolded into space and time: :func:`unfold_up`, the first chunk dropping the frames before frame 0).
* **Encoder**: causal conv in, down stages, mid block, norm, SiLU, causal conv to 2·z_dim; then a 1x1x1 conv
  (``quant_conv``). The posterior is a diagonal Gaussian (mean, log-variance clamped to [-30, 20]);
  :meth:`GaussianPosterior.mode` is its mean.
* **Decoder**: 1x1x1 conv (``post_quant_conv``), causal conv in, mid block, up stages, norm, SiLU, causal conv
  out; the output is clamped to [-1, 1].

The layers are in :mod:`._wan_vae_layers`. Time is processed in chunks, as the reference does, with a
:class:`~._wan_vae_layers.FrameCache` carrying between chunks the last two
input frames of every causal convolution (and the last frame of every temporal downsampler): the encoder takes
frame 0, then frames 1-4, 5-8, ... (frames past the last whole group of 4 are not encoded); the decoder takes one
latent frame at a time. Chunking keeps one chunk's activations in memory and makes the arithmetic the
reference's, operation for operation.

Spatial tiling (:meth:`WanVAE.enable_tiling`: overlapping tiles, blended linearly) and batch slicing
(:meth:`WanVAE.enable_slicing`) save memory on large videos, as in the reference. Not supported (refused naming the
field): ``patch_size`` (the Wan 2.2 5B VAE), ``attn_scales`` (the reference's encoder cannot run with it).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from ._wan_vae_layers import CausalConv3d, Decoder3d, Encoder3d, FrameCache
from .configured import ConfiguredModule
from .errors import CheckpointLayoutError
from .weights import CONFIG_NAME

__all__ = ["WanVAE", "GaussianPosterior", "check_wan_vae_config", "WAN_2_1_LATENTS_MEAN", "WAN_2_1_LATENTS_STD"]

#: pixel frames per encoder chunk after the first (which is frame 0 alone)
ENCODE_CHUNK = 4

#: per-channel latent statistics of the Wan 2.1 VAE (its release; the defaults of ``latents_mean`` / ``latents_std``)
WAN_2_1_LATENTS_MEAN = (
    -0.7571, -0.7089, -0.9113, 0.1075, -0.1745, 0.9653, -0.1517, 1.5508,
    0.4134, -0.0715, 0.5517, -0.3632, -0.1922, -0.9497, 0.2503, -0.2921,
)  # fmt: skip
WAN_2_1_LATENTS_STD = (
    2.8184, 1.4541, 2.3275, 2.6558, 1.2196, 1.7708, 2.6052, 2.0743,
    3.2687, 2.1526, 2.8652, 1.5579, 1.6382, 1.1253, 2.8251, 1.9160,
)  # fmt: skip


# ---------------------------------------------------------------------------------------------------- outputs
class GaussianPosterior:
    """Diagonal Gaussian over latents from ``moments`` (B, 2·z, T', H', W'): mean, then log-variance (clamped to
    [-30, 20])."""

    def __init__(self, moments: torch.Tensor) -> None:
        self.parameters = moments
        self.mean, logvar = torch.chunk(moments, 2, dim=1)
        self.logvar = torch.clamp(logvar, -30.0, 20.0)
        self.std = torch.exp(0.5 * self.logvar)
        self.var = torch.exp(self.logvar)

    def mode(self) -> torch.Tensor:
        """The mean (B, z, T', H', W'): the deterministic latent."""
        return self.mean

    def sample(self, generator: torch.Generator | None = None) -> torch.Tensor:
        """mean + std · ε, ε standard normal drawn by ``generator`` (on its device, then moved) or torch's global one."""
        device = generator.device if generator is not None else self.mean.device
        eps = torch.randn(self.mean.shape, generator=generator, device=device, dtype=self.mean.dtype)
        return self.mean + self.std * eps.to(self.mean.device)


@dataclass
class EncodeOutput:
    """What :meth:`WanVAE.encode` returns: ``latent_dist``, the posterior."""

    latent_dist: GaussianPosterior


@dataclass
class DecodeOutput:
    """What :meth:`WanVAE.decode` returns: ``sample``, pixels (B, C_out, T, H, W) in [-1, 1]."""

    sample: torch.Tensor


# ---------------------------------------------------------------------------------------------------- config
def check_wan_vae_config(config, source=CONFIG_NAME) -> None:
    """Refuse settings :class:`WanVAE` does not compute (CheckpointLayoutError naming ``source`` and the field)."""
    if config.get("patch_size") is not None:
        raise CheckpointLayoutError(
            source,
            "patch_size",
            "null (oscar's Wan VAE has no patchified input: not the Wan 2.2 5B VAE)",
            repr(config["patch_size"]),
        )
    if list(config.get("attn_scales") or []):
        raise CheckpointLayoutError(
            source, "attn_scales", "[] (attention only in the mid block)", config["attn_scales"]
        )
    dim_mult, down = list(config.get("dim_mult", [1, 2, 4, 4])), config.get("temperal_downsample", [False, True, True])
    if len(dim_mult) < 1 or len(list(down)) != len(dim_mult) - 1:
        raise CheckpointLayoutError(
            source,
            "temperal_downsample",
            f"one flag per down stage ({len(dim_mult) - 1} for dim_mult {dim_mult})",
            list(down),
        )


# ---------------------------------------------------------------------------------------------------- the model
def _encode_chunks(frames: int) -> list[slice]:
    """Frame 0 alone, then groups of :data:`ENCODE_CHUNK` (a partial last group is left out, as the reference does)."""
    return [slice(0, 1)] + [slice(1 + ENCODE_CHUNK * i, 1 + ENCODE_CHUNK * (i + 1)) for i in range((frames - 1) // 4)]


class WanVAE(ConfiguredModule):
    """The Wan VAE (module docstring): ``encode(pixels).latent_dist.mode()`` → latents, ``decode(z).sample`` → pixels.

    Settings are diffusers' ``AutoencoderKLWan``'s (same names, defaults: the Wan 2.1 VAE). ``decoder_base_dim``
    None means ``base_dim``; ``scale_factor_spatial`` is the tile arithmetic's latent-to-pixel factor (kept as
    written even where it differs from the network's); ``scale_factor_temporal`` is recorded only.
    """

    config_class_name = "AutoencoderKLWan"

    def __init__(
        self,
        base_dim: int = 96,
        decoder_base_dim: int | None = None,
        z_dim: int = 16,
        dim_mult=(1, 2, 4, 4),
        num_res_blocks: int = 2,
        attn_scales=(),
        temperal_downsample=(False, True, True),
        dropout: float = 0.0,
        latents_mean=WAN_2_1_LATENTS_MEAN,
        latents_std=WAN_2_1_LATENTS_STD,
        is_residual: bool = False,
        in_channels: int = 3,
        out_channels: int = 3,
        patch_size: int | None = None,
        scale_factor_temporal: int | None = 4,
        scale_factor_spatial: int | None = 8,
    ) -> None:
        super().__init__()
        check_wan_vae_config(self.config)
        dim_mult, down = list(dim_mult), [bool(v) for v in temperal_downsample]
        self.z_dim = z_dim
        self.encoder = Encoder3d(in_channels, base_dim, z_dim * 2, dim_mult, num_res_blocks, down, dropout, is_residual)
        self.quant_conv = CausalConv3d(z_dim * 2, z_dim * 2, 1)
        self.post_quant_conv = CausalConv3d(z_dim, z_dim, 1)
        self.decoder = Decoder3d(
            decoder_base_dim or base_dim,
            z_dim,
            dim_mult,
            num_res_blocks,
            down[::-1],
            dropout,
            out_channels,
            is_residual,
        )
        self.spatial_compression_ratio = scale_factor_spatial
        self.use_slicing = False
        self.use_tiling = False
        self.tile_sample_min_height = self.tile_sample_min_width = 256  # pixels
        self.tile_sample_stride_height = self.tile_sample_stride_width = 192

    # ------------------------------------------------------------------ options
    def enable_tiling(
        self,
        tile_sample_min_height=None,
        tile_sample_min_width=None,
        tile_sample_stride_height=None,
        tile_sample_stride_width=None,
    ) -> None:
        """Encode and decode above ``tile_sample_min_*`` pixels in tiles that far apart by ``tile_sample_stride_*``
        pixels (defaults 256 and 192), blending the overlaps linearly (less memory; seams differ slightly)."""
        self.use_tiling = True
        self.tile_sample_min_height = tile_sample_min_height or self.tile_sample_min_height
        self.tile_sample_min_width = tile_sample_min_width or self.tile_sample_min_width
        self.tile_sample_stride_height = tile_sample_stride_height or self.tile_sample_stride_height
        self.tile_sample_stride_width = tile_sample_stride_width or self.tile_sample_stride_width

    def disable_tiling(self) -> None:
        self.use_tiling = False

    def enable_slicing(self) -> None:
        """Encode and decode one batch element at a time (less memory)."""
        self.use_slicing = True

    def disable_slicing(self) -> None:
        self.use_slicing = False

    # ------------------------------------------------------------------ encode
    def encode(self, x: torch.Tensor) -> EncodeOutput:
        """Pixels (B, C_in, T, H, W) in [-1, 1] → ``EncodeOutput(latent_dist)``, a posterior over (B, z, 1 + (T-1)//4,
        H/s, W/s) latents."""
        parts = x.split(1) if self.use_slicing and x.shape[0] > 1 else [x]
        return EncodeOutput(GaussianPosterior(torch.cat([self._encode(p) for p in parts])))

    def _encode(self, x: torch.Tensor) -> torch.Tensor:
        height, width = x.shape[-2:]
        if self.use_tiling and (width > self.tile_sample_min_width or height > self.tile_sample_min_height):
            return self._tiled_encode(x)
        return self.quant_conv(self._encode_frames(x))

    def _encode_frames(self, x: torch.Tensor, each=None) -> torch.Tensor:
        """The encoder over ``x``'s chunks (:func:`_encode_chunks`) with one cache; ``each`` applied to each chunk's
        output before they are joined in time."""
        cache, outs = FrameCache(), []
        for chunk in _encode_chunks(x.shape[2]):
            cache.start_chunk()
            out = self.encoder(x[:, :, chunk], cache)
            outs.append(each(out) if each else out)
        return torch.cat(outs, 2)

    # ------------------------------------------------------------------ decode
    def decode(self, z: torch.Tensor) -> DecodeOutput:
        """Latents (B, z, T', H', W') (un-normalised) → ``DecodeOutput(sample)``, pixels (B, C_out, 1 + 4(T'-1), s·H',
        s·W') clamped to [-1, 1]."""
        parts = z.split(1) if self.use_slicing and z.shape[0] > 1 else [z]
        return DecodeOutput(torch.cat([self._decode(p) for p in parts]))

    def _decode(self, z: torch.Tensor) -> torch.Tensor:
        ratio = self.spatial_compression_ratio
        height, width = z.shape[-2:]
        if self.use_tiling and (
            width > self.tile_sample_min_width // ratio or height > self.tile_sample_min_height // ratio
        ):
            return self._tiled_decode(z)
        return torch.clamp(self._decode_frames(self.post_quant_conv(z)), min=-1.0, max=1.0)

    def _decode_frames(self, x: torch.Tensor, before=None) -> torch.Tensor:
        """The decoder over ``x``'s latent frames one at a time with one cache (``before`` applied to each first)."""
        cache, outs = FrameCache(), []
        for i in range(x.shape[2]):
            cache.start_chunk()
            frame = x[:, :, i : i + 1]
            outs.append(self.decoder(before(frame) if before else frame, cache, first_chunk=i == 0))
        return torch.cat(outs, 2)

    def forward(self, sample: torch.Tensor, sample_posterior: bool = False, generator=None) -> DecodeOutput:
        """decode(encode(sample)) through the posterior's mode (or a sample of it)."""
        posterior = self.encode(sample).latent_dist
        return self.decode(posterior.sample(generator) if sample_posterior else posterior.mode())

    # ------------------------------------------------------------------ tiling
    def _tiled_encode(self, x: torch.Tensor) -> torch.Tensor:
        """Encode overlapping spatial tiles (each over all chunks) and blend them: (B, C, T, H, W) → moments."""
        ratio = self.spatial_compression_ratio
        th, tw = self.tile_sample_min_height, self.tile_sample_min_width
        sh, sw = self.tile_sample_stride_height, self.tile_sample_stride_width
        rows = [
            [
                self._encode_frames(x[:, :, :, i : i + th, j : j + tw], each=self.quant_conv)
                for j in range(0, x.shape[-1], sw)
            ]
            for i in range(0, x.shape[-2], sh)
        ]
        keep_h, keep_w = sh // ratio, sw // ratio
        out = _blend_tiles(rows, th // ratio - keep_h, tw // ratio - keep_w, keep_h, keep_w)
        return out[:, :, :, : x.shape[-2] // ratio, : x.shape[-1] // ratio]

    def _tiled_decode(self, z: torch.Tensor) -> torch.Tensor:
        """Decode overlapping spatial tiles of latents and blend them: (B, z, T', H', W') → pixels, clamped."""
        ratio = self.spatial_compression_ratio
        th, tw = self.tile_sample_min_height // ratio, self.tile_sample_min_width // ratio
        sh, sw = self.tile_sample_stride_height // ratio, self.tile_sample_stride_width // ratio
        rows = [
            [
                self._decode_frames(z[:, :, :, i : i + th, j : j + tw], before=self.post_quant_conv)
                for j in range(0, z.shape[-1], sw)
            ]
            for i in range(0, z.shape[-2], sh)
        ]
        ph, pw = self.tile_sample_stride_height, self.tile_sample_stride_width
        out = _blend_tiles(rows, self.tile_sample_min_height - ph, self.tile_sample_min_width - pw, ph, pw)
        return torch.clamp(out[:, :, :, : z.shape[-2] * ratio, : z.shape[-1] * ratio], min=-1.0, max=1.0)

    @classmethod
    def from_folder(cls, folder, device="cpu") -> WanVAE:
        """The model of a ``vae/`` folder (config.json + safetensors), loaded strictly (:func:`.weights.build_strict`)."""
        from .weights import build_strict, load_state_dict, read_config

        config = read_config(folder, (cls.config_class_name,))
        check_wan_vae_config(config, Path(folder) / CONFIG_NAME)
        return build_strict(cls, config, load_state_dict(folder, device=device), folder)


def _blend_tiles(rows, blend_h: int, blend_w: int, keep_h: int, keep_w: int) -> torch.Tensor:
    """Join a grid of tiles (B, C, T, h, w): each tile's first ``blend_*`` rows/columns fade in from its upper/left
    neighbour's last ones, then its first ``keep_*`` rows/columns are kept."""
    joined = []
    for i, row in enumerate(rows):
        kept = []
        for j, tile in enumerate(row):
            if i > 0:
                tile = _fade(rows[i - 1][j], tile, blend_h, dim=3)
            if j > 0:
                tile = _fade(row[j - 1], tile, blend_w, dim=4)
            kept.append(tile[:, :, :, :keep_h, :keep_w])
        joined.append(torch.cat(kept, dim=-1))
    return torch.cat(joined, dim=3)


def _fade(a: torch.Tensor, b: torch.Tensor, extent: int, dim: int) -> torch.Tensor:
    """b with its first ``extent`` slices along ``dim`` replaced by a linear fade from a's last ones (in place)."""
    extent = min(a.shape[dim], b.shape[dim], extent)
    for k in range(extent):
        b.select(dim, k).copy_(a.select(dim, k - extent) * (1 - k / extent) + b.select(dim, k) * (k / extent))
    return b
