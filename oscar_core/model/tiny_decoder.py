"""A tiny video decoder for the WAN 2.1 latent space (the TAEHV design; ``taew2_1`` weights by key name).

The full WAN VAE decoder is a causal 3-D network that costs most of a closed-loop step on the CPU. TAEHV
("Tiny AutoEncoder for Hunyuan Video", whose ``taew2_1`` checkpoint targets the WAN 2.1 latents of the 2B model)
decodes the same latents with a stack of 2-D convolutions applied to every latent frame at once, with time
carried by *memory blocks* (each sees its own input one frame earlier, zeros before the first frame) and
*time-grow* layers (a 1x1 convolution that turns each frame into ``stride`` frames). Written here from that
description; the layer order and the key names follow the published checkpoint's state dict, so its weights load
by name (:func:`load_tiny_decoder`).

The decoder, as an ``nn.Sequential`` named ``decoder`` (index: layer), with widths ``(256, 128, 64, 64)``:

====  =========================================================================================
0     soft clamp ``3 tanh(x / 3)``
1, 2  3x3 convolution ``z -> 256`` (with bias), ReLU
3-5   three memory blocks at 256 channels
6-8   nearest upsampling (x2 in space or x1), time-grow at stride 1, 3x3 convolution ``256 -> 128`` (no bias)
9-11  three memory blocks at 128
12-14 upsampling, time-grow (stride 2 or 1), 3x3 convolution ``128 -> 64`` (no bias)
15-17 three memory blocks at 64
18-20 upsampling, time-grow (stride 2 or 1), 3x3 convolution ``64 -> 64`` (no bias)
21,22 ReLU, 3x3 convolution ``64 -> 3`` (with bias)
====  =========================================================================================

A memory block holds ``conv`` (3x3 ``2C -> C``, ReLU, 3x3, ReLU, 3x3; keys ``conv.0``, ``conv.2``, ``conv.4``) applied
to the channel concatenation ``[x_t, x_{t-1}]``, plus a skip (identity at equal widths), then a ReLU. A time-grow
layer's key is ``conv.weight`` (``(C * stride, C, 1, 1)``); its output channels ``[jC, (j+1)C)`` are output frame
``j`` of the input frame. The output is RGB in about [0, 1], clamped; with two stride-2 time-grows T' latent frames
give 4T' frames, of which the first 3 are dropped (WAN's first latent frame covers one frame): 4(T' − 1) + 1, as
the full decoder gives.

Input: *un-normalised* WAN latents, the ones ``AutoencoderKLWan.decode`` takes; :class:`TinyVideoDecoder` takes the
normalised latents of :class:`~oscar_core.model.vae.VideoVAE` and undoes the normalisation first.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from torch import nn

from ._taehv_blocks import MemoryBlock, conv3, read_prefixed_tensors, run_with_memory
from .errors import CheckpointLayoutError
from .weights import check_safetensors

__all__ = [
    "TinyDecoderNet",
    "TinyVideoDecoder",
    "load_tiny_decoder",
    "architecture_metadata",
    "save_tiny_decoder",
    "TAEW2_1_WIDTHS",
    "ARCHITECTURE_KEY",
]

#: channel widths of the ``taew2_1`` decoder's three stages and its last convolution
TAEW2_1_WIDTHS = (256, 128, 64, 64)
#: the safetensors metadata key under which a file written by oscar keeps its decoder's shape (a JSON object of
#: TinyDecoderNet's arguments); a file without it (the published ``taew2_1``) is read at ``taew2_1``'s shape
ARCHITECTURE_KEY = "oscar_tiny_decoder"
_ARCH_FIELDS = ("latent_channels", "space_upscale", "time_upscale", "widths")


class _SoftClamp(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return 3.0 * torch.tanh(x / 3.0)


class _TimeGrow(nn.Module):
    """(N*T, C, H, W) -> (N*T*stride, C, H, W): each frame becomes ``stride`` frames through one 1x1 convolution."""

    def __init__(self, channels: int, stride: int):
        super().__init__()
        self.stride = stride
        self.conv = nn.Conv2d(channels, channels * stride, 1, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        nt, c, h, w = x.shape
        return self.conv(x).reshape(nt * self.stride, c, h, w)


class TinyDecoderNet(nn.Module):
    """The decoder network (module docstring). latent_channels: z (16 for WAN 2.1); space_upscale,
    time_upscale: per stage whether it doubles height and width / the frame count (``taew2_1``: (True, True, True)
    and (False, True, True)); widths: the stages' channels. ``forward``: (N, T', z, h, w) un-normalised latents
    -> (N, 4T' − 3, 3, H, W) RGB in [0, 1] (with two time doublings; ``frames_to_trim`` in general)."""

    def __init__(
        self,
        latent_channels: int = 16,
        space_upscale: tuple[bool, bool, bool] = (True, True, True),
        time_upscale: tuple[bool, bool, bool] = (False, True, True),
        widths: tuple[int, int, int, int] = TAEW2_1_WIDTHS,
    ):
        super().__init__()
        self.latent_channels = int(latent_channels)
        self.space_upscale, self.time_upscale, self.widths = tuple(space_upscale), tuple(time_upscale), tuple(widths)
        w = widths
        layers: list[nn.Module] = [_SoftClamp(), conv3(latent_channels, w[0]), nn.ReLU()]
        for stage in range(3):
            layers += [MemoryBlock(w[stage], w[stage]) for _ in range(3)]
            layers += [
                nn.Upsample(scale_factor=2 if space_upscale[stage] else 1),
                _TimeGrow(w[stage], 2 if time_upscale[stage] else 1),
                conv3(w[stage], w[stage + 1], bias=False),
            ]
        layers += [nn.ReLU(), conv3(w[3], 3)]
        self.decoder = nn.Sequential(*layers)
        self.time_factor = 2 ** sum(bool(t) for t in time_upscale)
        self.space_factor = 2 ** sum(bool(s) for s in space_upscale)
        self.frames_to_trim = self.time_factor - 1

    def forward(self, latents: torch.Tensor) -> torch.Tensor:
        n, t, c, h, w = latents.shape
        x = run_with_memory(self.decoder, latents.reshape(n * t, c, h, w), n)
        x = x.reshape(n, x.shape[0] // n, *x.shape[1:]).clamp_(0.0, 1.0)
        return x[:, self.frames_to_trim :]


def architecture_metadata(net: TinyDecoderNet) -> dict[str, str]:
    """The safetensors metadata that records ``net``'s shape (read back by :func:`load_tiny_decoder`)."""
    arch = {
        "latent_channels": net.latent_channels,
        "space_upscale": [bool(v) for v in net.space_upscale],
        "time_upscale": [bool(v) for v in net.time_upscale],
        "widths": [int(v) for v in net.widths],
    }
    return {ARCHITECTURE_KEY: json.dumps(arch)}


def save_tiny_decoder(net: TinyDecoderNet, path) -> None:
    """Write ``net``'s weights (float32, CPU) to the safetensors file ``path``, its shape in the metadata
    (:func:`architecture_metadata`), atomically; the parent folder is created."""
    from safetensors.torch import save

    from .._util.atomic import atomic_write_bytes

    path = Path(path)
    tensors = {k: v.detach().float().cpu().contiguous() for k, v in net.state_dict().items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, save(tensors, metadata=architecture_metadata(net)))


def _net_from_metadata(path: Path) -> TinyDecoderNet:
    """The net the file's metadata describes (``taew2_1``'s shape when it has none); CheckpointLayoutError naming the
    file and the field on a malformed description."""
    from safetensors import safe_open

    with safe_open(str(path), "pt") as f:
        meta = f.metadata() or {}
    if ARCHITECTURE_KEY not in meta:
        return TinyDecoderNet()
    field = f"metadata {ARCHITECTURE_KEY}"
    expected = f"a JSON object of {list(_ARCH_FIELDS)} (three booleans per upscale, four widths)"
    try:
        arch = json.loads(meta[ARCHITECTURE_KEY])
        ok = isinstance(arch, dict) and set(arch) == set(_ARCH_FIELDS)
        ok = ok and all(len(arch[k]) == 3 and all(isinstance(v, bool) for v in arch[k]) for k in _ARCH_FIELDS[1:3])
        ok = ok and len(arch["widths"]) == 4 and all(isinstance(v, int) and v > 0 for v in arch["widths"])
        ok = ok and isinstance(arch["latent_channels"], int) and arch["latent_channels"] > 0
    except (ValueError, TypeError):
        ok = False
    if not ok:
        raise CheckpointLayoutError(path, field, expected, repr(meta[ARCHITECTURE_KEY])[:120])
    return TinyDecoderNet(**{k: tuple(v) if isinstance(v, list) else v for k, v in arch.items()})


def load_tiny_decoder(path, net: TinyDecoderNet | None = None) -> TinyDecoderNet:
    """A :class:`TinyDecoderNet` with the ``decoder.*`` tensors of the safetensors file ``path``, of the shape its
    metadata records (:data:`ARCHITECTURE_KEY`, written by oscar's training) or else ``taew2_1``'s, unless ``net``
    is given; other keys (the checkpoint's ``encoder.*``) are ignored. A time-grow weight stored
    with more output channels than the layer has (trained at a larger stride) keeps its last ones (the last output
    frame's). Raises CheckpointLayoutError naming the file and the key on a missing, unexpected or misshapen
    tensor. Pickle files are refused (safetensors only)."""
    path = Path(path)
    if path.suffix != ".safetensors":
        raise CheckpointLayoutError(path, "tiny decoder", "a .safetensors file of decoder weights", path.name)
    if not path.is_file():
        raise CheckpointLayoutError(path, "tiny decoder", "a weights file", "no such file")
    check_safetensors(path)  # a truncated or garbled file: CheckpointIntegrityError before any tensor is read
    net = net if net is not None else _net_from_metadata(path)
    want = net.state_dict()
    stored = read_prefixed_tensors(path, "decoder.", want, "the tiny decoder")
    for key, tensor in want.items():
        value = stored[key]
        grow = key.endswith(".conv.weight") and isinstance(net.decoder[int(key.split(".")[1])], _TimeGrow)
        if grow and value.shape[0] > tensor.shape[0] and value.shape[1:] == tensor.shape[1:]:
            value = value[-tensor.shape[0] :]
        if value.shape != tensor.shape:
            raise CheckpointLayoutError(path, key, f"shape {tuple(tensor.shape)}", str(tuple(value.shape)))
        stored[key] = value.to(torch.float32)
    net.load_state_dict({k: stored[k] for k in want})
    return net.eval()


class TinyVideoDecoder:
    """The tiny decoder behind :meth:`VideoVAE.decode`'s contract: normalised latents (B, z, T', h, w) -> pixels
    (B, 3, 4(T' − 1) + 1, H, W) float32 in [-1, 1]. net: a loaded :class:`TinyDecoderNet`; mean, std: the VAE's
    (1, z, 1, 1, 1) latent normalisation; device, dtype: where and how it runs.

    On the CPU a batch is decoded one clip at a time: the toy decoder's activations for 4 clips at once (17 frames
    of 64 x 64 at 32 channels) outgrow the caches, and a batch of 4 cost 122 CPU ms per clip against 67 ms clip by
    clip (one thread, the same values bit for bit). On a GPU the batch goes through in one call."""

    def __init__(self, net: TinyDecoderNet, mean: torch.Tensor, std: torch.Tensor, device="cpu", dtype=torch.float32):
        self.net = net.to(device=device, dtype=dtype).eval()
        self.mean, self.std = mean, std
        self.device, self.dtype = torch.device(device), dtype

    @torch.no_grad()
    def decode(self, latents: torch.Tensor) -> torch.Tensor:
        if self.device.type == "cpu" and latents.shape[0] > 1:
            return torch.cat([self.decode(latents[i : i + 1]) for i in range(latents.shape[0])])
        z = latents.float() * self.std.to(latents.device) + self.mean.to(latents.device)
        x = self.net(z.to(self.device, self.dtype).permute(0, 2, 1, 3, 4))  # (B, T, 3, H, W) in [0, 1]
        return x.float().permute(0, 2, 1, 3, 4).mul(2.0).sub(1.0)
