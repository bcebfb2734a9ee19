"""A tiny video encoder for the WAN 2.1 latent space (the TAEHV design; ``taew2_1``'s encoder weights by key name).

The closed loop encodes every chunk's condition video (the skeleton) with the full WAN VAE encoder, a causal 3-D
network; on the 2B model that encode is most of a step once the decode is tiny (docs/closed-loop.md). TAEHV's
encoder, the other half of the tiny decoder (:mod:`.tiny_decoder`), maps frames to the same latents with 2-D
convolutions applied to every frame at once. Time enters in two ways: *memory blocks* (as in the decoder: each sees
its own input one frame earlier, zeros before a clip's first frame) and *time pools* (a 1x1 convolution over the
channels of ``stride`` consecutive frames stacked, which turns them into one frame). Written here from that
description; the layer order and the key names follow the published checkpoint, whose ``encoder.*`` tensors sit
beside its ``decoder.*`` ones, so its encoder loads by name (:func:`load_tiny_encoder`).

The encoder, an ``nn.Sequential`` named ``encoder`` (index: layer), all at ``width`` channels (64 in ``taew2_1``):

=====  ===========================================================================================
0, 1   3x3 convolution ``3 -> width`` (with bias), ReLU
2      time pool at stride 2 (or 1): ``conv.weight`` ``(width, stride * width, 1, 1)``
3      3x3 convolution ``width -> width``, stride 2 (or 1) in space, no bias
4-6    three memory blocks
7-11   time pool, strided convolution, three memory blocks (the second stage)
12-16  time pool (stride 1 in ``taew2_1``), strided convolution, three memory blocks (the third stage)
17     3x3 convolution ``width -> z`` (with bias)
=====  ===========================================================================================

A time pool's input channels ``[jC, (j+1)C)`` are frame ``j`` of the frames it pools (the earliest first). With
``taew2_1``'s two pools at stride 2 a latent frame summarises 4 input frames. The frame count: a clip of T frames is
first padded at its end with copies of its last frame up to a multiple of 4, so WAN's 4k + 1 frames give
k + 1 latent frames (latent frame j covers input frames 4j to 4j + 3, the last one frame 4k repeated), the count the
full encoder gives; through the memory blocks latent frame j also sees every earlier frame, never a later one.

Input: RGB in [0, 1], (N, T, 3, H, W); output: *un-normalised* WAN latents (N, T', z, H/8, W/8), what
``AutoencoderKLWan.encode`` gives (its posterior's mode). :class:`TinyVideoEncoder` puts it behind
:meth:`~oscar_core.model.vae.VideoVAE.encode`'s contract: [-1, 1] pixels (B, 3, 4k + 1, H, W) in, *normalised*
latents (B, z, k + 1, H/8, W/8) out.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from torch import nn

from ._taehv_blocks import MemoryBlock, conv3, read_prefixed_tensors, run_with_memory
from .chunks import check_frame_count
from .errors import CheckpointLayoutError, ModelInputError
from .weights import check_safetensors

__all__ = [
    "TinyEncoderNet",
    "TinyVideoEncoder",
    "load_tiny_encoder",
    "save_tiny_encoder",
    "encoder_architecture_metadata",
    "TAEW2_1_ENCODER_WIDTH",
    "ENCODER_ARCHITECTURE_KEY",
]

#: channels of every stage of the ``taew2_1`` encoder
TAEW2_1_ENCODER_WIDTH = 64
#: the safetensors metadata key under which a file written by oscar keeps its encoder's shape (a JSON object of
#: TinyEncoderNet's arguments); a file without it (the published ``taew2_1``) is read at ``taew2_1``'s shape
ENCODER_ARCHITECTURE_KEY = "oscar_tiny_encoder"
_ARCH_FIELDS = ("latent_channels", "space_downscale", "time_downscale", "width")


class _TimePool(nn.Module):
    """(N*T, C, H, W) -> (N*T/stride, C, H, W): each run of ``stride`` consecutive frames (channels stacked, the
    earliest first) becomes one frame through one 1x1 convolution. T must be a multiple of ``stride``."""

    def __init__(self, channels: int, stride: int):
        super().__init__()
        self.stride = stride
        self.conv = nn.Conv2d(channels * stride, channels, 1, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        nt, c, h, w = x.shape
        return self.conv(x.reshape(nt // self.stride, self.stride * c, h, w))


class TinyEncoderNet(nn.Module):
    """The encoder network (module docstring). latent_channels: z (16 for WAN 2.1); space_downscale,
    time_downscale: per stage whether it halves height and width / the frame count (``taew2_1``: (True, True, True)
    and (True, True, False)); width: the channels of every stage. ``forward``: (N, T, 3, H, W) RGB in [0, 1], T of
    any length (padded at the end to a multiple of ``time_factor`` with its last frame) -> (N, ceil(T /
    time_factor), z, H / space_factor, W / space_factor) un-normalised latents."""

    def __init__(
        self,
        latent_channels: int = 16,
        space_downscale: tuple[bool, bool, bool] = (True, True, True),
        time_downscale: tuple[bool, bool, bool] = (True, True, False),
        width: int = TAEW2_1_ENCODER_WIDTH,
    ):
        super().__init__()
        self.latent_channels, self.width = int(latent_channels), int(width)
        self.space_downscale, self.time_downscale = tuple(space_downscale), tuple(time_downscale)
        w = self.width
        layers: list[nn.Module] = [conv3(3, w), nn.ReLU()]
        for stage in range(3):
            layers += [
                _TimePool(w, 2 if time_downscale[stage] else 1),
                conv3(w, w, bias=False, stride=2 if space_downscale[stage] else 1),
            ]
            layers += [MemoryBlock(w, w) for _ in range(3)]
        layers.append(conv3(w, latent_channels))
        self.encoder = nn.Sequential(*layers)
        self.time_factor = 2 ** sum(bool(t) for t in time_downscale)
        self.space_factor = 2 ** sum(bool(s) for s in space_downscale)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        n, t, c, h, w = frames.shape
        if c != 3 or h % self.space_factor or w % self.space_factor:
            raise ModelInputError(
                f"tiny encoder input: expected (N, T, 3, H, W) with H and W divisible by {self.space_factor}, "
                f"found {tuple(frames.shape)}"
            )
        pad = -t % self.time_factor
        if pad:
            frames = torch.cat([frames, frames[:, -1:].expand(n, pad, c, h, w)], dim=1)
        x = run_with_memory(self.encoder, frames.reshape(n * (t + pad), c, h, w), n)
        return x.reshape(n, x.shape[0] // n, *x.shape[1:])


def encoder_architecture_metadata(net: TinyEncoderNet) -> dict[str, str]:
    """The safetensors metadata that records ``net``'s shape (read back by :func:`load_tiny_encoder`)."""
    arch = {
        "latent_channels": net.latent_channels,
        "space_downscale": [bool(v) for v in net.space_downscale],
        "time_downscale": [bool(v) for v in net.time_downscale],
        "width": net.width,
    }
    return {ENCODER_ARCHITECTURE_KEY: json.dumps(arch)}


def save_tiny_encoder(net: TinyEncoderNet, path) -> None:
    """Write ``net``'s weights (float32, CPU) to the safetensors file ``path``, its shape in the metadata
    (:func:`encoder_architecture_metadata`), atomically; the parent folder is created."""
    from safetensors.torch import save

    from .._util.atomic import atomic_write_bytes

    path = Path(path)
    tensors = {k: v.detach().float().cpu().contiguous() for k, v in net.state_dict().items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, save(tensors, metadata=encoder_architecture_metadata(net)))


def _net_from_metadata(path: Path) -> TinyEncoderNet:
    """The net the file's metadata describes (``taew2_1``'s shape when it has none); CheckpointLayoutError naming the
    file and the field on a malformed description."""
    from safetensors import safe_open

    with safe_open(str(path), "pt") as f:
        meta = f.metadata() or {}
    if ENCODER_ARCHITECTURE_KEY not in meta:
        return TinyEncoderNet()
    try:
        arch = json.loads(meta[ENCODER_ARCHITECTURE_KEY])
        ok = isinstance(arch, dict) and set(arch) == set(_ARCH_FIELDS)
        ok = ok and all(len(arch[k]) == 3 and all(isinstance(v, bool) for v in arch[k]) for k in _ARCH_FIELDS[1:3])
        ok = ok and all(isinstance(arch[k], int) and arch[k] > 0 for k in ("latent_channels", "width"))
    except (ValueError, TypeError):
        ok = False
    if not ok:
        raise CheckpointLayoutError(
            path,
            f"metadata {ENCODER_ARCHITECTURE_KEY}",
            f"a JSON object of {list(_ARCH_FIELDS)} (three booleans per downscale, a positive width)",
            repr(meta[ENCODER_ARCHITECTURE_KEY])[:120],
        )
    return TinyEncoderNet(**{k: tuple(v) if isinstance(v, list) else v for k, v in arch.items()})


def load_tiny_encoder(path, net: TinyEncoderNet | None = None) -> TinyEncoderNet:
    """A :class:`TinyEncoderNet` with the ``encoder.*`` tensors of the safetensors file ``path``, of the shape its
    metadata records (:data:`ENCODER_ARCHITECTURE_KEY`, written by oscar's training) or else ``taew2_1``'s, unless
    ``net`` is given; other keys (the checkpoint's ``decoder.*``) are ignored. Raises CheckpointLayoutError naming the
    file and the key on a missing, unexpected or misshapen tensor. Pickle files are refused (safetensors only)."""
    path = Path(path)
    if path.suffix != ".safetensors":
        raise CheckpointLayoutError(path, "tiny encoder", "a .safetensors file of encoder weights", path.name)
    if not path.is_file():
        raise CheckpointLayoutError(path, "tiny encoder", "a weights file", "no such file")
    check_safetensors(path)  # a truncated or garbled file: CheckpointIntegrityError before any tensor is read
    net = net if net is not None else _net_from_metadata(path)
    want = net.state_dict()
    stored = read_prefixed_tensors(path, "encoder.", want, "the tiny encoder")
    for key, tensor in want.items():
        if stored[key].shape != tensor.shape:
            raise CheckpointLayoutError(path, key, f"shape {tuple(tensor.shape)}", str(tuple(stored[key].shape)))
    net.load_state_dict({k: stored[k].to(torch.float32) for k in want})
    return net.eval()


class TinyVideoEncoder:
    """The tiny encoder behind :meth:`VideoVAE.encode`'s contract: pixels (B, 3, 4k + 1, H, W) in [-1, 1] ->
    normalised latents (B, z, k + 1, H / s, W / s) float32, s the net's space factor. net: a loaded
    :class:`TinyEncoderNet`; mean, std: the VAE's (1, z, 1, 1, 1) latent normalisation; device, dtype: where and how
    it runs. A frame count not of the form 4k + 1 is refused (ModelInputError), as the full encoder refuses it."""

    def __init__(self, net: TinyEncoderNet, mean: torch.Tensor, std: torch.Tensor, device="cpu", dtype=torch.float32):
        self.net = net.to(device=device, dtype=dtype).eval()
        self.mean, self.std = mean, std
        self.device, self.dtype = torch.device(device), dtype

    @torch.no_grad()
    def encode(self, pixels: torch.Tensor) -> torch.Tensor:
        if pixels.ndim != 5 or pixels.shape[1] != 3:
            raise ModelInputError(f"pixels: expected (B, 3, T, H, W), found shape {tuple(pixels.shape)}")
        check_frame_count(int(pixels.shape[2]), self.net.time_factor, "tiny encoder input")
        x = pixels.to(self.device, self.dtype).add(1.0).mul(0.5).permute(0, 2, 1, 3, 4)  # (B, T, 3, H, W) in [0, 1]
        z = self.net(x).float().permute(0, 2, 1, 3, 4)  # (B, z, T', h, w), un-normalised
        return (z - self.mean.to(z.device)) / self.std.to(z.device)
