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
* **RMS norm** (:class:`RMSNorm`): each pixel's channel vector divided by its L2 norm, times sqrt(C) and a learnt
  per-channel gain (float32 arithmetic for half-precision inputs).
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

Time is processed in chunks, as the reference does, with a :class:`FrameCache` carrying between chunks the last two
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
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from .configured import ConfiguredModule
from .errors import CheckpointLayoutError
from .weights import CONFIG_NAME

__all__ = ["WanVAE", "GaussianPosterior", "check_wan_vae_config", "WAN_2_1_LATENTS_MEAN", "WAN_2_1_LATENTS_STD"]

#: frames of its input a causal 3-D convolution keeps for the next chunk (its kernel is 3 frames deep)
CACHE_FRAMES = 2
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


# ---------------------------------------------------------------------------------------------------- frame cache
class FrameCache:
    """What each causal layer kept of the previous chunk, one slot per layer in call order.

    ``start_chunk()`` before each chunk rewinds the cursor; each layer then calls :meth:`swap` once per chunk, in the
    same order every chunk. A slot is None before the layer's first chunk.
    """

    def __init__(self) -> None:
        self.slots: list[Any] = []
        self.cursor = 0

    def start_chunk(self) -> None:
        self.cursor = 0

    def swap(self, keep) -> Any:
        """The next slot's content (None on the first chunk), replaced by ``keep(content)``."""
        if self.cursor == len(self.slots):
            self.slots.append(None)
        old = self.slots[self.cursor]
        self.slots[self.cursor] = keep(old)
        self.cursor += 1
        return old


def _tail(x: torch.Tensor, past: torch.Tensor | None) -> torch.Tensor:
    """The last :data:`CACHE_FRAMES` frames of ``x`` (B, C, T, H, W), completed from ``past`` when T is 1."""
    tail = x[:, :, -CACHE_FRAMES:].clone()
    if tail.shape[2] < CACHE_FRAMES and past is not None:
        tail = torch.cat([past[:, :, -1:].to(tail.device), tail], dim=2)
    return tail


# ---------------------------------------------------------------------------------------------------- layers
class CausalConv3d(nn.Conv3d):
    """A ``Conv3d`` padded causally in time: ``2 p_t`` frames before the clip, none after; ``p_h``, ``p_w`` both sides.

    ``forward(x, cache)``: x (B, C_in, T, H, W) → (B, C_out, T', H', W'). With a :class:`FrameCache` the frames the
    layer kept from the previous chunk stand in for (part of) the zero padding, and this chunk's last frames are kept.
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size, stride=1, padding=0) -> None:
        super().__init__(in_channels, out_channels, kernel_size, stride=stride, padding=padding)
        pt, ph, pw = self.padding
        self.causal_pad = (pw, pw, ph, ph, 2 * pt, 0)  # F.pad order: W, H, then T (before, after)
        self.padding = (0, 0, 0)  # the padding is done by F.pad in forward

    def forward(self, x: torch.Tensor, cache: FrameCache | None = None) -> torch.Tensor:
        past = cache.swap(lambda old: _tail(x, old)) if cache is not None else None
        return self.padded_conv(x, past)

    def padded_conv(self, x: torch.Tensor, past: torch.Tensor | None = None) -> torch.Tensor:
        """The convolution of ``past`` frames (B, C, P, H, W) followed by ``x``, zeros making up the causal padding."""
        pad = list(self.causal_pad)
        if past is not None and pad[4] > 0:
            x = torch.cat([past.to(x.device), x], dim=2)
            pad[4] -= past.shape[2]
        return super().forward(F.pad(x, pad))


class RMSNorm(nn.Module):
    """x / ||x||_channels · sqrt(C) · gamma over dim 1 of (B, C, T, H, W) (``images=False``) or (B, C, H, W)."""

    def __init__(self, dim: int, images: bool = True) -> None:
        super().__init__()
        self.scale = dim**0.5
        self.gamma = nn.Parameter(torch.ones((dim, 1, 1) if images else (dim, 1, 1, 1)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        half = x.dtype in (torch.float16, torch.bfloat16) or "float8_" in str(x.dtype) or "float4_" in str(x.dtype)
        unit = F.normalize(x.float() if half else x, dim=1).to(x.dtype)
        return unit * self.scale * self.gamma


class ResidualBlock(nn.Module):
    """(norm, SiLU, causal 3x3x3 conv) twice (dropout before the second conv) + shortcut: (B, C_in, T, H, W) →
    (B, C_out, T, H, W)."""

    def __init__(self, in_dim: int, out_dim: int, dropout: float = 0.0) -> None:
        super().__init__()
        self.norm1 = RMSNorm(in_dim, images=False)
        self.conv1 = CausalConv3d(in_dim, out_dim, 3, padding=1)
        self.norm2 = RMSNorm(out_dim, images=False)
        self.dropout = nn.Dropout(dropout)
        self.conv2 = CausalConv3d(out_dim, out_dim, 3, padding=1)
        self.conv_shortcut = CausalConv3d(in_dim, out_dim, 1) if in_dim != out_dim else nn.Identity()

    def forward(self, x: torch.Tensor, cache: FrameCache | None = None) -> torch.Tensor:
        skip = self.conv_shortcut(x)
        x = self.conv1(F.silu(self.norm1(x)), cache)
        x = self.conv2(self.dropout(F.silu(self.norm2(x))), cache)
        return x + skip


class FrameAttention(nn.Module):
    """Single-head self-attention among the H·W pixels of each frame, plus the input: (B, C, T, H, W) → same."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.norm = RMSNorm(dim)
        self.to_qkv = nn.Conv2d(dim, dim * 3, 1)
        self.proj = nn.Conv2d(dim, dim, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, c, t, h, w = x.shape
        frames = x.permute(0, 2, 1, 3, 4).reshape(b * t, c, h, w)
        qkv = self.to_qkv(self.norm(frames)).reshape(b * t, 1, c * 3, h * w)
        q, k, v = qkv.permute(0, 1, 3, 2).contiguous().chunk(3, dim=-1)  # each (B·T, 1, H·W, C)
        out = F.scaled_dot_product_attention(q, k, v)
        out = self.proj(out.squeeze(1).permute(0, 2, 1).reshape(b * t, c, h, w))
        return out.view(b, t, c, h, w).permute(0, 2, 1, 3, 4) + x


class MidBlock(nn.Module):
    """Residual block, frame attention, residual block, at one width: (B, C, T, H, W) → same."""

    def __init__(self, dim: int, dropout: float = 0.0) -> None:
        super().__init__()
        first = ResidualBlock(dim, dim, dropout)  # built in this order: the reference's default init draws so
        attention = FrameAttention(dim)
        second = ResidualBlock(dim, dim, dropout)
        self.attentions = nn.ModuleList([attention])
        self.resnets = nn.ModuleList([first, second])

    def forward(self, x: torch.Tensor, cache: FrameCache) -> torch.Tensor:
        x = self.resnets[0](x, cache)
        return self.resnets[1](self.attentions[0](x), cache)


class NearestUp2x(nn.Module):
    """Nearest-exact x2 upsampling in space of (N, C, H, W), computed in float32, returned in the input's dtype."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.interpolate(x.float(), scale_factor=(2.0, 2.0), mode="nearest-exact").type_as(x)


class Resample(nn.Module):
    """x2 down- or upsampling in space, optionally in time (module docstring).

    mode: ``"down2d"``, ``"down3d"``, ``"up2d"``, ``"up3d"``; out_dim: the width after an upsampling conv.
    Shapes: down3d (B, C, T, H, W) → (B, C, T', H/2, W/2) with T' = T for the first chunk (frame 0 alone) and T/2
    after; up3d → (B, out_dim, T', 2H, 2W) with T' = T for the first chunk (one latent frame) and 2T after; the 2d
    modes keep T.
    """

    def __init__(self, dim: int, mode: str, out_dim: int | None = None) -> None:
        super().__init__()
        self.mode = mode
        if mode.startswith("up"):
            self.resample = nn.Sequential(NearestUp2x(), nn.Conv2d(dim, out_dim or dim // 2, 3, padding=1))
        else:
            self.resample = nn.Sequential(nn.ZeroPad2d((0, 1, 0, 1)), nn.Conv2d(dim, dim, 3, stride=(2, 2)))
        if mode == "up3d":
            self.time_conv = CausalConv3d(dim, dim * 2, (3, 1, 1), padding=(1, 0, 0))
        elif mode == "down3d":
            self.time_conv = CausalConv3d(dim, dim, (3, 1, 1), stride=(2, 1, 1))

    def forward(self, x: torch.Tensor, cache: FrameCache) -> torch.Tensor:
        if self.mode == "up3d":
            x = self._double_frames(x, cache)
        b, c, t, h, w = x.shape
        y = self.resample(x.permute(0, 2, 1, 3, 4).reshape(b * t, c, h, w))
        y = y.view(b, t, y.shape[1], y.shape[2], y.shape[3]).permute(0, 2, 1, 3, 4)
        return self._halve_frames(y, cache) if self.mode == "down3d" else y

    def _double_frames(self, x: torch.Tensor, cache: FrameCache) -> torch.Tensor:
        """(B, C, T, H, W) → (B, C, 2T, H, W) by the time conv; the first chunk passes unchanged and leaves zeros
        as the conv's past (so the conv starts afresh at the second chunk)."""
        past = cache.swap(lambda old: torch.zeros_like(x[:, :, -1:]) if old is None else _tail(x, old))
        if past is None:
            return x
        b, c, t, h, w = x.shape
        y = self.time_conv.padded_conv(x, past).reshape(b, 2, c, t, h, w)
        return torch.stack((y[:, 0], y[:, 1]), 3).reshape(b, c, t * 2, h, w)

    def _halve_frames(self, y: torch.Tensor, cache: FrameCache) -> torch.Tensor:
        """(B, C, T, H, W) → the time conv at stride 2 over the previous chunk's last frame and y; the first chunk
        passes unchanged."""
        past = cache.swap(lambda old: y.clone() if old is None else y[:, :, -1:].clone())
        if past is None:
            return y
        return self.time_conv(torch.cat([past[:, :, -1:], y], 2))


# ---------------------------------------------------------------------------------------------------- Wan 2.2 shortcuts
def fold_down(x: torch.Tensor, out_channels: int, factor_t: int, factor_s: int) -> torch.Tensor:
    """Wan 2.2's down-stage shortcut: (B, C, T, H, W) → (B, out_channels, ceil(T/f_t), H/f_s, W/f_s).

    Time is zero-padded at the front to a multiple of f_t; each f_t x f_s x f_s block is folded into channels
    (channel-major: c, then t, h, w offsets) and consecutive groups of C·f_t·f_s² / out_channels channels averaged.
    """
    x = F.pad(x, (0, 0, 0, 0, (factor_t - x.shape[2] % factor_t) % factor_t, 0))
    b, c, t, h, w = x.shape
    t2, h2, w2 = t // factor_t, h // factor_s, w // factor_s
    x = x.view(b, c, t2, factor_t, h2, factor_s, w2, factor_s).permute(0, 1, 3, 5, 7, 2, 4, 6).contiguous()
    group = c * factor_t * factor_s * factor_s // out_channels
    return x.view(b, out_channels, group, t2, h2, w2).mean(dim=2)


def unfold_up(x: torch.Tensor, out_channels: int, factor_t: int, factor_s: int, first_chunk: bool) -> torch.Tensor:
    """Wan 2.2's up-stage shortcut: (B, C, T, H, W) → (B, out_channels, T·f_t, H·f_s, W·f_s), the inverse layout of
    :func:`fold_down` after each channel is repeated out_channels·f_t·f_s² / C times; the first chunk drops its first
    f_t - 1 frames."""
    b, c, t, h, w = x.shape
    x = x.repeat_interleave(out_channels * factor_t * factor_s * factor_s // c, dim=1)
    x = x.view(b, out_channels, factor_t, factor_s, factor_s, t, h, w).permute(0, 1, 5, 2, 6, 3, 7, 4).contiguous()
    x = x.view(b, out_channels, t * factor_t, h * factor_s, w * factor_s)
    return x[:, :, factor_t - 1 :] if first_chunk else x


def _check_fold(in_dim: int, out_dim: int, factor: int) -> None:
    if in_dim * factor % out_dim:
        raise CheckpointLayoutError(
            CONFIG_NAME,
            "base_dim/dim_mult",
            f"widths whose ratio divides the down factor {factor}",
            f"{in_dim} → {out_dim}",
        )


# ---------------------------------------------------------------------------------------------------- stages
class ResidualDownStage(nn.Module):
    """Wan 2.2 encoder stage: residual blocks, optional downsampling, plus :func:`fold_down` of its input."""

    def __init__(self, in_dim: int, out_dim: int, dropout: float, num_res_blocks: int, down_t: bool, down_s: bool):
        super().__init__()
        self.out_dim, self.factor_t, self.factor_s = out_dim, 2 if down_t else 1, 2 if down_s else 1
        _check_fold(in_dim, out_dim, self.factor_t * self.factor_s**2)
        dims = [in_dim] + [out_dim] * num_res_blocks
        self.resnets = nn.ModuleList(ResidualBlock(a, b, dropout) for a, b in zip(dims[:-1], dims[1:]))
        self.downsampler = Resample(out_dim, "down3d" if down_t else "down2d") if down_s else None

    def forward(self, x: torch.Tensor, cache: FrameCache) -> torch.Tensor:
        skip = x  # nothing below writes into x
        for block in self.resnets:
            x = block(x, cache)
        if self.downsampler is not None:
            x = self.downsampler(x, cache)
        return x + fold_down(skip, self.out_dim, self.factor_t, self.factor_s)


class UpStage(nn.Module):
    """Wan 2.1 decoder stage: num_res_blocks + 1 residual blocks, then optional upsampling (halving the width)."""

    def __init__(self, in_dim: int, out_dim: int, num_res_blocks: int, dropout: float, mode: str | None):
        super().__init__()
        dims = [in_dim] + [out_dim] * (num_res_blocks + 1)
        self.resnets = nn.ModuleList(ResidualBlock(a, b, dropout) for a, b in zip(dims[:-1], dims[1:]))
        self.upsamplers = nn.ModuleList([Resample(out_dim, mode)]) if mode else None

    def forward(self, x: torch.Tensor, cache: FrameCache, first_chunk: bool = False) -> torch.Tensor:
        for block in self.resnets:
            x = block(x, cache)
        return self.upsamplers[0](x, cache) if self.upsamplers is not None else x


class ResidualUpStage(nn.Module):
    """Wan 2.2 decoder stage: residual blocks, optional upsampling (width kept), plus :func:`unfold_up` of its
    input."""

    def __init__(self, in_dim: int, out_dim: int, num_res_blocks: int, dropout: float, up_t: bool, up_s: bool):
        super().__init__()
        self.out_dim, self.factor_t = out_dim, 2 if up_t else 1
        self.up = up_s
        if up_s and (out_dim * self.factor_t * 4) % in_dim:
            raise CheckpointLayoutError(
                CONFIG_NAME,
                "decoder_base_dim/dim_mult",
                "widths whose ratio divides the up factor",
                f"{in_dim} → {out_dim}",
            )
        dims = [in_dim] + [out_dim] * (num_res_blocks + 1)
        self.resnets = nn.ModuleList(ResidualBlock(a, b, dropout) for a, b in zip(dims[:-1], dims[1:]))
        self.upsampler = Resample(out_dim, "up3d" if up_t else "up2d", out_dim=out_dim) if up_s else None

    def forward(self, x: torch.Tensor, cache: FrameCache, first_chunk: bool = False) -> torch.Tensor:
        skip = x  # nothing below writes into x
        for block in self.resnets:
            x = block(x, cache)
        if self.upsampler is None:
            return x
        return self.upsampler(x, cache) + unfold_up(skip, self.out_dim, self.factor_t, 2, first_chunk)


# ---------------------------------------------------------------------------------------------------- encoder / decoder
def _head(norm: RMSNorm, conv: CausalConv3d, x: torch.Tensor, cache: FrameCache) -> torch.Tensor:
    return conv(F.silu(norm(x)), cache)


class Encoder3d(nn.Module):
    """Pixels (B, C_in, T, H, W) of one chunk → (B, z_out, T', H/s, W/s) (module docstring)."""

    def __init__(self, in_channels, dim, z_out, dim_mult, num_res_blocks, temperal_downsample, dropout, is_residual):
        super().__init__()
        dims = [dim * m for m in (1, *dim_mult)]
        self.conv_in = CausalConv3d(in_channels, dims[0], 3, padding=1)
        self.down_blocks = nn.ModuleList()
        last = len(dim_mult) - 1
        for i, (a, b) in enumerate(zip(dims[:-1], dims[1:])):
            down_t = bool(temperal_downsample[i]) if i != last else False
            if is_residual:
                self.down_blocks.append(ResidualDownStage(a, b, dropout, num_res_blocks, down_t, i != last))
                continue
            for a_k in [a] + [b] * (num_res_blocks - 1):
                self.down_blocks.append(ResidualBlock(a_k, b, dropout))
            if i != last:
                self.down_blocks.append(Resample(b, "down3d" if down_t else "down2d"))
        self.mid_block = MidBlock(dims[-1], dropout)
        self.norm_out = RMSNorm(dims[-1], images=False)
        self.conv_out = CausalConv3d(dims[-1], z_out, 3, padding=1)

    def forward(self, x: torch.Tensor, cache: FrameCache) -> torch.Tensor:
        x = self.conv_in(x, cache)
        for layer in self.down_blocks:
            x = layer(x, cache)
        return _head(self.norm_out, self.conv_out, self.mid_block(x, cache), cache)


class Decoder3d(nn.Module):
    """Latents (B, z_dim, T', H', W') of one chunk → pixels (B, C_out, T, s·H', s·W') (module docstring)."""

    def __init__(self, dim, z_dim, dim_mult, num_res_blocks, temperal_upsample, dropout, out_channels, is_residual):
        super().__init__()
        dims = [dim * m for m in (dim_mult[-1], *dim_mult[::-1])]
        self.conv_in = CausalConv3d(z_dim, dims[0], 3, padding=1)
        self.mid_block = MidBlock(dims[0], dropout)
        self.up_blocks = nn.ModuleList()
        last = len(dim_mult) - 1
        for i, (a, b) in enumerate(zip(dims[:-1], dims[1:])):
            up_t = bool(temperal_upsample[i]) if i != last else False
            if is_residual:
                self.up_blocks.append(ResidualUpStage(a, b, num_res_blocks, dropout, up_t, i != last))
            else:
                mode = None if i == last else ("up3d" if up_t else "up2d")
                self.up_blocks.append(UpStage(a // 2 if i > 0 else a, b, num_res_blocks, dropout, mode))
        self.norm_out = RMSNorm(dims[-1], images=False)
        self.conv_out = CausalConv3d(dims[-1], out_channels, 3, padding=1)

    def forward(self, x: torch.Tensor, cache: FrameCache, first_chunk: bool = False) -> torch.Tensor:
        x = self.mid_block(self.conv_in(x, cache), cache)
        for stage in self.up_blocks:
            x = stage(x, cache, first_chunk)
        return _head(self.norm_out, self.conv_out, x, cache)


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
