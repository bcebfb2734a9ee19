"""The Wan VAE's layers (:mod:`.wan_vae` has the model, its architecture and shapes): the frame cache that carries
causal convolutions from one time chunk to the next, the causal 3-D convolution, RMS norm, residual and attention
blocks, resamplers, the Wan 2.2 shortcuts, the down/up stages, and the encoder and decoder over one chunk.

Names and nesting of the sub-modules are diffusers' ``AutoencoderKLWan``'s, so state-dict keys match theirs.
"""

from __future__ import annotations

import math
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from .errors import CheckpointLayoutError
from .weights import CONFIG_NAME

__all__ = ["CACHE_FRAMES", "FrameCache", "CausalConv3d", "RMSNorm", "Encoder3d", "Decoder3d"]

#: frames of its input a causal 3-D convolution keeps for the next chunk (its kernel is 3 frames deep)
CACHE_FRAMES = 2


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


#: the fewest elements per channel for which :func:`channel_norm_by_sums` beats ``torch.linalg.vector_norm`` on the CPU
#: (measured on the toy VAE's norms: below it the per-channel adds' overhead costs more than the norm kernel)
SUM_NORM_MIN_ELEMENTS = 1024
#: rows that torch's CPU sum over an outer dimension adds one after another before it starts a second partial sum
#: (its cascade sum's first level); more channels are added to that partial sum one by one
_SEQUENTIAL_SUM_ROWS = 16


def channel_norm_by_sums(x: torch.Tensor) -> torch.Tensor:
    """The L2 norm over dim 1 of a float32 CPU tensor (B, C, ...) → (B, 1, ...), bit for bit what
    ``torch.linalg.vector_norm(x, 2, dim=1, keepdim=True)`` gives when dim 1 is not the innermost dimension in memory.

    torch's CPU norm of such a tensor adds each position's C squares one after another in float32 and takes a
    correctly rounded square root, one output element at a time (no vector instructions across positions). Here the
    squares are one vectorised product, their running sum is a sum over the first 16 channels (which torch's CPU sum
    also adds one after another) followed by one in-place add per further channel, and the square root is taken in
    float64 and rounded to float32 (correctly rounded: float64 carries more than twice float32's precision; torch's
    float32 ``sqrt`` on the CPU is not always). About 4x faster on the toy VAE's activations; tests/model/
    test_wan_vae_norm.py checks the bit-identity over channel counts, layouts and sizes on the installed torch.
    """
    squares = x * x
    total = squares[:, :_SEQUENTIAL_SUM_ROWS].sum(1, keepdim=True)
    for c in range(_SEQUENTIAL_SUM_ROWS, x.shape[1]):
        total += squares[:, c : c + 1]
    return total.double().sqrt_().float()


def _sum_norm_applies(x: torch.Tensor) -> bool:
    """Whether :func:`channel_norm_by_sums` gives ``F.normalize``'s norm of ``x`` bit for bit and faster: float32 on the
    CPU, channels not innermost in memory, innermost dimension contiguous, at least :data:`SUM_NORM_MIN_ELEMENTS` per
    channel, and no autograd graph to build (training keeps the reference's operations and their gradients)."""
    return (
        x.dtype == torch.float32
        and x.device.type == "cpu"
        and x.dim() >= 3
        and x.stride(1) != 1
        and x.stride(-1) == 1
        and math.prod(x.shape[2:]) >= SUM_NORM_MIN_ELEMENTS
        and not torch.is_grad_enabled()
    )


class RMSNorm(nn.Module):
    """x / max(||x||_channels, 1e-12) · sqrt(C) · gamma over dim 1 of (B, C, T, H, W) (``images=False``) or
    (B, C, H, W), as diffusers' ``WanRMS_norm`` (``F.normalize``: eps 1e-12 bounds the norm from below); half
    precision is normalised in float32. Float32 without autograd on the CPU takes its norm from
    :func:`channel_norm_by_sums` where that is bit-identical and faster (:func:`_sum_norm_applies`), else (and for
    every other dtype and device) from ``F.normalize``."""

    def __init__(self, dim: int, images: bool = True) -> None:
        super().__init__()
        self.scale = dim**0.5
        self.gamma = nn.Parameter(torch.ones((dim, 1, 1) if images else (dim, 1, 1, 1)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.gamma.dtype == x.dtype and _sum_norm_applies(x):  # in place: the reference's values, fewer copies
            return torch.div(x, channel_norm_by_sums(x).clamp_min_(1e-12)).mul_(self.scale).mul_(self.gamma)
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
