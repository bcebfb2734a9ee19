"""The layers of Cosmos-Predict2.5's DiT in plain torch, named so that checkpoints load without renaming.

Every parameter sits where the diffusers checkpoints of Cosmos-Predict2.5 put it (``attn1.to_q.weight``,
``ff.net.0.proj.weight``, ``norm1.linear_1.weight``, ...), so a state dict moves between these layers and
diffusers' ``CosmosTransformer3DModel`` unchanged; :mod:`.cosmos_dit` assembles them. The arithmetic follows the
order diffusers 0.42.1 uses, step for step, so float32 outputs agree bit for bit on the CPU (tests/model/
test_cosmos_dit.py checks it against diffusers itself).

Shapes: B batch, N tokens (T' H' W' after patching), D hidden size (heads x head_dim), L context tokens,
M timesteps (B, or B T' for one timestep per latent frame).
"""

from __future__ import annotations

import contextlib
import math
from collections import OrderedDict

import torch
import torch.nn.functional as F
from torch import nn

from .errors import ModelInputError

__all__ = [
    "RMSNorm",
    "PatchEmbed",
    "RotaryPositions",
    "LearnablePositions",
    "TimestepEmbedding",
    "AdaLNModulation",
    "Attention",
    "FeedForward",
    "TransformerBlock",
    "apply_rotary",
    "sinusoid",
]

#: frame rate the temporal RoPE positions are expressed in when the caller passes ``fps``
ROPE_BASE_FPS = 24
#: RoPE base period before the NTK rescaling by ``rope_scale``
ROPE_THETA = 10000.0
#: rotary tables a :class:`RotaryPositions` keeps, the least recently used dropped first (a rollout calls the DiT
#: with one grid, device and fps at every step; a few more cover a chunk size or fps changing within a session)
ROPE_TABLES_KEPT = 4
#: period of the slowest sinusoid of the timestep features
TIME_PERIOD = 10000.0


class RMSNorm(nn.Module):
    """``x / rms(x) * weight`` over the last dimension, the mean square taken in float32.

    The result is float32 unless the weight is float16/bfloat16 (then it is cast to the weight's dtype before the
    scaling), as diffusers' ``RMSNorm`` does. x: (..., dim) → (..., dim).
    """

    def __init__(self, dim: int, eps: float) -> None:
        super().__init__()
        self.eps = eps
        self.weight = nn.Parameter(torch.ones(dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        inv_rms = torch.rsqrt(x.float().pow(2).mean(-1, keepdim=True) + self.eps)
        normed = x * inv_rms
        if self.weight.dtype in (torch.float16, torch.bfloat16):
            normed = normed.to(self.weight.dtype)
        return normed * self.weight


class PatchEmbed(nn.Module):
    """One linear map per (p_t, p_h, p_w) patch: (B, C, T, H, W) → (B, T', H', W', D).

    The patch is flattened channel-major, (C, p_t, p_h, p_w), which is the column order of ``proj.weight``
    in Cosmos checkpoints.
    """

    def __init__(self, channels: int, dim: int, patch_size: tuple[int, int, int], bias: bool = False) -> None:
        super().__init__()
        self.patch_size = tuple(int(p) for p in patch_size)
        self.proj = nn.Linear(channels * math.prod(self.patch_size), dim, bias=bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, c, t, h, w = x.shape
        p_t, p_h, p_w = self.patch_size
        patches = x.reshape(b, c, t // p_t, p_t, h // p_h, p_h, w // p_w, p_w)
        return self.proj(patches.permute(0, 2, 4, 6, 1, 3, 5, 7).flatten(4))


def _axis_dims(head_dim: int) -> tuple[int, int, int]:
    """Channels of a head given to the (time, height, width) rotary angles: height and width a third each
    (rounded down to even), time the rest."""
    spatial = head_dim // 6 * 2
    return head_dim - 2 * spatial, spatial, spatial


def _inverse_frequencies(dim: int, theta: float) -> torch.Tensor:
    """(dim // 2,) float32 ``theta ** (-2i / dim)``."""
    exponents = torch.arange(0, dim, 2, dtype=torch.float32)[: dim // 2] / dim
    return 1.0 / (theta**exponents)


class RotaryPositions(nn.Module):
    """3-D rotary angles of a (T', H', W') token grid: cos, sin of shape (N, head_dim), float32.

    A head's channels are split (time, height, width) by :func:`_axis_dims`; each axis has its own NTK-scaled
    period ``10000 * rope_scale ** (d / (d - 2))``. Positions are token indices; with ``fps`` the time index
    is counted in frames of 24 fps (``index / fps * 24``). The angles are laid out [t, h, w, t, h, w] so the
    two halves of a head rotate together (:func:`apply_rotary`). No parameters.

    The tables depend on nothing but (grid, device, fps), so the last :data:`ROPE_TABLES_KEPT` are kept and returned
    again (the same tensors: callers must not write into them); they are made outside inference mode and without
    autograd, so tables first made in a rollout serve a training step too. Moving the module (``.to``) drops them;
    under ``torch.compile`` they are computed in the graph as before.
    """

    def __init__(self, head_dim: int, max_grid: tuple[int, int, int], rope_scale: tuple[float, float, float]):
        super().__init__()
        self.dims = _axis_dims(head_dim)
        self.thetas = tuple(ROPE_THETA * float(s) ** (d / (d - 2)) for s, d in zip(rope_scale, self.dims))
        self.longest = max(max_grid)
        self._tables: OrderedDict[tuple, tuple[torch.Tensor, torch.Tensor]] = OrderedDict()

    def forward(self, grid: tuple[int, int, int], device, fps: float | None = None):
        if max(grid) > self.longest:
            raise ModelInputError(
                f"latent grid: expected at most {self.longest} tokens along each axis (max_size / patch_size "
                f"of the model's config), found {tuple(grid)}"
            )
        if torch.compiler.is_compiling() or not isinstance(fps, (int, float, type(None))):
            return self.tables(grid, device, fps)
        key = (tuple(int(n) for n in grid), torch.device(device), None if fps is None else float(fps))
        kept = self._tables.get(key)
        if kept is not None:
            with contextlib.suppress(KeyError):  # another thread may have dropped it meanwhile
                self._tables.move_to_end(key)
            return kept
        with torch.inference_mode(False), torch.no_grad():
            made = self._tables[key] = self.tables(grid, device, fps)
        while len(self._tables) > ROPE_TABLES_KEPT:
            self._tables.popitem(last=False)
        return made

    def _apply(self, fn, *args, **kwargs):
        self._tables.clear()  # .to(device / dtype) and friends: tables of the old placement are not kept
        return super()._apply(fn, *args, **kwargs)

    def tables(self, grid: tuple[int, int, int], device, fps: float | None = None):
        """(cos, sin) of the angles of ``grid``, each (T' H' W', head_dim) float32, computed afresh."""
        positions = [torch.arange(n, dtype=torch.float32, device=device) for n in grid]
        if fps is not None:
            positions[0] = positions[0] / fps * ROPE_BASE_FPS
        angles = [
            torch.outer(pos, _inverse_frequencies(d, theta).to(device))
            for pos, d, theta in zip(positions, self.dims, self.thetas)
        ]
        t, h, w = grid
        per_axis = [
            angles[0][:, None, None, :].expand(t, h, w, -1),
            angles[1][None, :, None, :].expand(t, h, w, -1),
            angles[2][None, None, :, :].expand(t, h, w, -1),
        ]
        angles_thw = torch.cat(per_axis * 2, dim=-1).flatten(0, 2)
        return torch.cos(angles_thw), torch.sin(angles_thw)


def apply_rotary(x: torch.Tensor, cos: torch.Tensor, sin: torch.Tensor) -> torch.Tensor:
    """Rotate (B, heads, N, d) queries or keys by (N, d) angles: channel i pairs with i + d/2.

    Computed in float32, returned in x's dtype.
    """
    first, second = x.unflatten(-1, (2, -1)).unbind(-2)
    turned = torch.cat([-second, first], dim=-1)
    return (x.float() * cos + turned.float() * sin).to(x.dtype)


class LearnablePositions(nn.Module):
    """A learnt embedding per time, row and column index, summed and RMS-normalised: (1, N, D) in ``dtype``.

    Parameters ``pos_emb_t`` (T_max', D), ``pos_emb_h`` (H_max', D), ``pos_emb_w`` (W_max', D), where
    the maxima are ``max_size // patch_size``. The normalisation is ``e / (eps + rms(e))``.
    """

    def __init__(self, dim: int, max_grid: tuple[int, int, int], eps: float = 1e-6) -> None:
        super().__init__()
        self.eps = eps
        self.max_grid = tuple(max_grid)
        self.pos_emb_t = nn.Parameter(torch.zeros(max_grid[0], dim))
        self.pos_emb_h = nn.Parameter(torch.zeros(max_grid[1], dim))
        self.pos_emb_w = nn.Parameter(torch.zeros(max_grid[2], dim))

    def forward(self, grid: tuple[int, int, int], dtype: torch.dtype) -> torch.Tensor:
        t, h, w = grid
        if t > self.max_grid[0] or h > self.max_grid[1] or w > self.max_grid[2]:
            raise ModelInputError(
                f"latent grid: expected at most {self.max_grid} tokens (max_size / patch_size of the model's "
                f"config, the size of its learnt positions), found {tuple(grid)}"
            )
        summed = self.pos_emb_t[:t, None, None] + self.pos_emb_h[None, :h, None] + self.pos_emb_w[None, None, :w]
        emb = summed.flatten(0, 2)
        norm = torch.linalg.vector_norm(emb, dim=-1, keepdim=True, dtype=torch.float32)
        norm = torch.add(self.eps, norm, alpha=math.sqrt(1 / emb.shape[-1]))
        return (emb / norm).to(dtype)[None]


def sinusoid(sigma: torch.Tensor, dim: int) -> torch.Tensor:
    """(M,) times → (M, dim) float32 features [cos(sigma f_i), sin(sigma f_i)], f_i = 10000 ** (-i / (dim/2))."""
    half = dim // 2
    exponents = -math.log(TIME_PERIOD) * torch.arange(half, dtype=torch.float32, device=sigma.device) / half
    angles = sigma[:, None].float() * torch.exp(exponents)[None, :]
    features = torch.cat([torch.cos(angles), torch.sin(angles)], dim=-1)
    return F.pad(features, (0, 1)) if dim % 2 else features


class _TimeMLP(nn.Module):
    """linear_1 (D → D), SiLU, linear_2 (D → 3D), no biases."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.linear_1 = nn.Linear(dim, dim, bias=False)
        self.linear_2 = nn.Linear(dim, 3 * dim, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.linear_2(F.silu(self.linear_1(x)))


class TimestepEmbedding(nn.Module):
    """(M,) flow times → (temb (M, 3D), embedded (M, D)) in ``dtype``.

    ``embedded`` is the RMS-normalised sinusoid (it feeds every AdaLN-LoRA); ``temb`` is the MLP of it, the
    (shift, scale, gate) added to each modulation.
    """

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.t_embedder = _TimeMLP(dim)
        self.norm = RMSNorm(dim, eps=1e-6)

    def forward(self, sigma: torch.Tensor, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
        features = sinusoid(sigma, self.norm.weight.shape[0]).to(dtype)
        return self.t_embedder(features), self.norm(features)


class AdaLNModulation(nn.Module):
    """AdaLN-LoRA: a parameter-free LayerNorm, then ``x (1 + scale) + shift``.

    (shift, scale[, gate]) = linear_2(linear_1(silu(embedded))) + temb[..., :chunks D]; ``embedded`` and
    ``temb`` are per sample (B, .) or per token (B, N, .). forward: x (B, N, D) → (modulated (B, N, D),
    gate (B, 1 or N, D) or None when chunks is 2).
    """

    def __init__(self, dim: int, lora_dim: int, chunks: int) -> None:
        super().__init__()
        self.chunks = chunks
        self.linear_1 = nn.Linear(dim, lora_dim, bias=False)
        self.linear_2 = nn.Linear(lora_dim, chunks * dim, bias=False)

    def forward(self, x: torch.Tensor, embedded: torch.Tensor, temb: torch.Tensor):
        dim = x.shape[-1]
        modulation = self.linear_2(self.linear_1(F.silu(embedded))) + temb[..., : self.chunks * dim]
        parts = modulation.chunk(self.chunks, dim=-1)
        if modulation.ndim == 2:
            parts = tuple(p.unsqueeze(1) for p in parts)
        modulated = F.layer_norm(x, (dim,), eps=1e-6) * (1 + parts[1]) + parts[0]
        return modulated, (parts[2] if self.chunks == 3 else None)


class Attention(nn.Module):
    """Multi-head attention with RMS-normalised queries and keys, through ``scaled_dot_product_attention``.

    Self-attention when ``context_dim`` is None (rotary angles applied to q and k), else cross-attention to a
    (B, L, context_dim) context. forward: x (B, N, D) → (B, N, D).
    """

    def __init__(self, dim: int, heads: int, head_dim: int, context_dim: int | None = None) -> None:
        super().__init__()
        inner = heads * head_dim
        self.heads = heads
        # registration order as in diffusers (norms first): seeded inits and parameter listings then agree
        self.norm_q = RMSNorm(head_dim, eps=1e-5)
        self.norm_k = RMSNorm(head_dim, eps=1e-5)
        self.to_q = nn.Linear(dim, inner, bias=False)
        self.to_k = nn.Linear(context_dim or dim, inner, bias=False)
        self.to_v = nn.Linear(context_dim or dim, inner, bias=False)
        self.to_out = nn.Sequential(nn.Linear(inner, dim, bias=False))

    def _split_heads(self, x: torch.Tensor) -> torch.Tensor:
        """(B, S, heads d) → (B, heads, S, d)."""
        return x.unflatten(-1, (self.heads, -1)).transpose(1, 2)

    def forward(self, x: torch.Tensor, context=None, rotary=None, mask=None) -> torch.Tensor:
        source = x if context is None else context
        q = self.norm_q(self._split_heads(self.to_q(x)))
        k = self.norm_k(self._split_heads(self.to_k(source)))
        v = self._split_heads(self.to_v(source))
        if rotary is not None:
            q, k = apply_rotary(q, *rotary), apply_rotary(k, *rotary)
        out = F.scaled_dot_product_attention(q, k, v, attn_mask=mask)
        return self.to_out(out.transpose(1, 2).flatten(2).type_as(q))


class _InProjection(nn.Module):
    """A linear layer kept under the name ``proj`` (checkpoint key ``ff.net.0.proj.weight``)."""

    def __init__(self, dim_in: int, dim_out: int) -> None:
        super().__init__()
        self.proj = nn.Linear(dim_in, dim_out, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(x)


class FeedForward(nn.Module):
    """Linear (D → mlp_ratio D), exact GELU, linear back; no biases. (B, N, D) → (B, N, D)."""

    def __init__(self, dim: int, mlp_ratio: float) -> None:
        super().__init__()
        inner = int(dim * mlp_ratio)
        self.net = nn.Sequential(_InProjection(dim, inner), nn.GELU(), nn.Linear(inner, dim, bias=False))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class TransformerBlock(nn.Module):
    """One DiT block: gated self-attention (RoPE), gated cross-attention to the text, gated MLP.

    Each branch reads an AdaLN-LoRA modulated copy of the tokens (``norm1``..``norm3``) and is added back
    times its gate. The learnt positions (when the model has them) are added before the block, and a
    ControlNet residual (when given) after it.
    """

    def __init__(self, heads: int, head_dim: int, text_dim: int, mlp_ratio: float, lora_dim: int) -> None:
        super().__init__()
        dim = heads * head_dim
        self.norm1 = AdaLNModulation(dim, lora_dim, chunks=3)
        self.attn1 = Attention(dim, heads, head_dim)
        self.norm2 = AdaLNModulation(dim, lora_dim, chunks=3)
        self.attn2 = Attention(dim, heads, head_dim, context_dim=text_dim)
        self.norm3 = AdaLNModulation(dim, lora_dim, chunks=3)
        self.ff = FeedForward(dim, mlp_ratio)

    def forward(self, x, context, embedded, temb, rotary=None, extra_pos=None, mask=None, residual=None):
        """x (B, N, D); context (B, L, text_dim); embedded (B, D) or (B, N, D); temb (B, 3D) or (B, N, 3D);
        rotary: (cos, sin) (N, head_dim); extra_pos (1, N, D); mask for the text keys; residual (B, N, D)."""
        if extra_pos is not None:
            x = x + extra_pos
        h, gate = self.norm1(x, embedded, temb)
        x = x + gate * self.attn1(h, rotary=rotary)
        h, gate = self.norm2(x, embedded, temb)
        x = x + gate * self.attn2(h, context=context, mask=mask)
        h, gate = self.norm3(x, embedded, temb)
        x = x + gate * self.ff(h)
        return x if residual is None else x + residual
