"""Layers the tiny encoder and the tiny decoder (the TAEHV design) share: the 3x3 convolution, the memory block,
the pass that hands every memory block its input one frame earlier, and the loader's key check.

Frames travel as one (N*T, C, H, W) batch of 2-D images (clip-major: the T frames of clip 0, then clip 1, ...);
only a memory block looks across time, and it looks one frame back.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from .errors import CheckpointLayoutError

__all__ = ["conv3", "MemoryBlock", "previous_frames", "run_with_memory", "read_prefixed_tensors"]


def conv3(n_in: int, n_out: int, bias: bool = True, stride: int = 1) -> nn.Conv2d:
    """A 3x3 convolution with padding 1 (``stride`` 2 halves height and width)."""
    return nn.Conv2d(n_in, n_out, 3, stride=stride, padding=1, bias=bias)


class MemoryBlock(nn.Module):
    """``relu(conv([x_t, x_{t-1}]) + skip(x_t))`` on (N*T, C, H, W) frames (the memory is passed in).

    ``conv``: 3x3 ``2C -> C``, ReLU, 3x3, ReLU, 3x3 (keys ``conv.0``, ``conv.2``, ``conv.4``); ``skip``: identity at
    equal widths, else a 1x1 convolution without bias."""

    def __init__(self, n_in: int, n_out: int):
        super().__init__()
        self.conv = nn.Sequential(
            conv3(2 * n_in, n_out), nn.ReLU(), conv3(n_out, n_out), nn.ReLU(), conv3(n_out, n_out)
        )
        self.skip = nn.Identity() if n_in == n_out else nn.Conv2d(n_in, n_out, 1, bias=False)

    def forward(self, x: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
        return torch.relu(self.conv(torch.cat([x, previous], dim=1)) + self.skip(x))


def previous_frames(x: torch.Tensor, clips: int) -> torch.Tensor:
    """(N*T, C, H, W) -> the same shape, each frame replaced by its clip's frame one step earlier (zeros for a
    clip's first frame)."""
    seq = x.reshape(clips, x.shape[0] // clips, *x.shape[1:])
    return torch.cat([torch.zeros_like(seq[:, :1]), seq[:, :-1]], dim=1).reshape(x.shape)


def run_with_memory(layers: nn.Sequential, x: torch.Tensor, clips: int) -> torch.Tensor:
    """Apply ``layers`` in order to (clips*T, C, H, W) frames, all frames at once, each :class:`MemoryBlock` given
    its input one frame earlier (:func:`previous_frames`); other layers may change the frame count (a time pool or
    time grow) as long as the frames stay clip-major."""
    for layer in layers:
        x = layer(x, previous_frames(x, clips)) if isinstance(layer, MemoryBlock) else layer(x)
    return x


def read_prefixed_tensors(path: Path, prefix: str, want: dict, what: str) -> dict:
    """The ``prefix``-keyed tensors of the safetensors file ``path`` (other keys ignored), checked to be exactly the
    keys of ``want`` (a state dict); CheckpointLayoutError naming the file, ``prefix``'s tensors, the missing and the
    unexpected keys otherwise. Shapes are the caller's to check."""
    from safetensors.torch import load_file

    stored = {k: v for k, v in load_file(str(path)).items() if k.startswith(prefix)}
    missing = sorted(set(want) - set(stored))
    extra = sorted(set(stored) - set(want))
    if missing or extra:
        found = [f"missing {missing[:5]}" if missing else "", f"unexpected {extra[:5]}" if extra else ""]
        raise CheckpointLayoutError(
            path, f"{prefix}* tensors", f"{what}'s {len(want)}", "; ".join(f for f in found if f)
        )
    return stored
