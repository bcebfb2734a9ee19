"""The WAN 2.1 VAE as the world model uses it: pixels ⇄ normalised latents.

Pixels are (B, 3, T, H, W) floats in [-1, 1] (or (T, H, W, 3) / (B, T, H, W, 3)
uint8 RGB through :meth:`VideoVAE.to_pixels`). Latents are (B, 16, T', H/8,
W/8) with T' = (T - 1) / 4 + 1, normalised per channel with the VAE's
``latents_mean``/``latents_std``: z_n = (z - mean) / std, exactly as the
Cosmos 2.5 pipeline does before the DiT, and undone before decoding.
Encoding takes the posterior's mode (the pipeline's "argmax"), so it is
deterministic. The VAE is causal in time: latent frame 0 depends only on
pixel frame 0, hence frame counts of the form 4k + 1.

A tiny decoder (:mod:`.tiny_decoder`, the TAEHV design, ``taew2_1`` weights for the 2B model's latents) can take
over :meth:`VideoVAE.decode` (:meth:`VideoVAE.use_tiny_decoder`); off by default: the full decoder decodes. A tiny
encoder (:mod:`.tiny_encoder`, the same design's encoder) can take over :meth:`VideoVAE.encode_condition`, the encode
of a rollout's condition video (:meth:`VideoVAE.use_tiny_encoder`); off by default, and never the seed frame's encode
(:meth:`VideoVAE.encode`).

The network is :class:`~.wan_vae.WanVAE`, oscar's own implementation of the Wan VAE (diffusers'
``AutoencoderKLWan``'s keys, config and numbers; no diffusers import on this path).

Memory options (for GPUs): spatial tiling and batch slicing, and CPU
offload — the VAE waits on the CPU and visits ``device`` only to encode or
decode. On the CPU its 3-D convolutions run through oneDNN at every batch size
(:mod:`.cpu_conv`).
"""

from __future__ import annotations

import numpy as np
import torch

from .chunks import check_frame_count  # kept importable from here, where it was before chunks.py
from .cpu_conv import use_onednn_conv3d
from .errors import ModelInputError
from .wan_vae import WanVAE
from .weights import cast_model

__all__ = ["VideoVAE", "check_frame_count", "load_vae_folder"]


def load_vae_folder(folder, device="cpu") -> WanVAE:
    """The :class:`~.wan_vae.WanVAE` of a diffusers-layout ``vae/`` folder, built by oscar's strict loader.

    config.json must name ``AutoencoderKLWan`` and hold only settings WanVAE computes; the safetensors weights must
    match its tensors exactly (CheckpointLayoutError naming the folder and the keys or the field otherwise).
    device: where the weights are read to (a GPU skips the host copy). Returns the model in eval mode.
    """
    return WanVAE.from_folder(folder, device=device)


class VideoVAE:
    """Wraps a :class:`~.wan_vae.WanVAE`: normalised latents in, [-1, 1] pixels out.

    vae: the VAE network (its config gives z_dim, latents_mean/std and the
        compression factors: 2^sum(temperal_downsample) in time, 2^len(...) in space).
    device: where encode/decode run; dtype: the VAE's compute dtype.
    offload: keep the VAE on the CPU between calls (GPU memory saver).
    """

    def __init__(self, vae, device="cpu", dtype: torch.dtype = torch.float32, offload: bool = False):
        self.vae = vae
        self.device = torch.device(device)
        self.dtype = dtype
        self.offload = offload
        cfg = vae.config
        self.temporal = 2 ** sum(bool(v) for v in cfg.temperal_downsample)
        self.spatial = 2 ** len(cfg.temperal_downsample)
        self.z_dim = int(cfg.z_dim)
        self.mean = torch.tensor(cfg.latents_mean, dtype=torch.float32).view(1, -1, 1, 1, 1)
        self.std = torch.tensor(cfg.latents_std, dtype=torch.float32).view(1, -1, 1, 1, 1)
        if self.mean.shape[1] != self.z_dim or self.std.shape[1] != self.z_dim:
            raise ModelInputError(
                f"VAE config: expected latents_mean/latents_std of length z_dim = {self.z_dim}, "
                f"found {self.mean.shape[1]} / {self.std.shape[1]}"
            )
        self.tiny = None  # a TinyVideoDecoder that decodes instead of the full decoder (use_tiny_decoder)
        self.tiny_encoder = (
            None  # a TinyVideoEncoder that encodes conditions instead of the full one (use_tiny_encoder)
        )
        cast_model(vae, "cpu" if offload else self.device, dtype)
        vae.eval()
        use_onednn_conv3d(vae)  # one clip on the CPU as fast per clip as a batch (cpu_conv.py)

    # ------------------------------------------------------------------ options
    def enable_tiling(self, **kwargs) -> None:
        """Spatial tiling of encode/decode (:meth:`.wan_vae.WanVAE.enable_tiling`; less memory, slight seams)."""
        self.vae.enable_tiling(**kwargs)

    def enable_slicing(self) -> None:
        """Encode/decode one batch element at a time."""
        self.vae.enable_slicing()

    def use_tiny_decoder(self, weights) -> None:
        """Decode with a tiny decoder from now on (:mod:`.tiny_decoder`): ``weights`` a safetensors file of
        ``decoder.*`` tensors (``taew2_1``'s key names and shapes) or a loaded ``TinyDecoderNet``; None goes back
        to the full decoder. Encoding is unchanged."""
        from .tiny_decoder import TinyDecoderNet, TinyVideoDecoder, load_tiny_decoder

        if weights is None:
            self.tiny = None
            return
        net = weights if isinstance(weights, TinyDecoderNet) else load_tiny_decoder(weights)
        if net.latent_channels != self.z_dim:
            raise ModelInputError(
                f"tiny decoder: expected {self.z_dim} latent channels (the VAE's z_dim), found {net.latent_channels}"
            )
        if net.time_factor != self.temporal or net.space_factor != self.spatial:
            raise ModelInputError(
                f"tiny decoder: expected x{self.temporal} in time and x{self.spatial} in space (the VAE's), "
                f"found x{net.time_factor} and x{net.space_factor}"
            )
        self.tiny = TinyVideoDecoder(net, self.mean, self.std, self.device, self.dtype)

    def use_tiny_encoder(self, weights) -> None:
        """Encode condition videos with a tiny encoder from now on (:mod:`.tiny_encoder`, :meth:`encode_condition`):
        ``weights`` a safetensors file of ``encoder.*`` tensors (``taew2_1``'s key names and shapes) or a loaded
        ``TinyEncoderNet``; None goes back to the full encoder. :meth:`encode` (the seed frame) is unchanged."""
        from .tiny_encoder import TinyEncoderNet, TinyVideoEncoder, load_tiny_encoder

        if weights is None:
            self.tiny_encoder = None
            return
        net = weights if isinstance(weights, TinyEncoderNet) else load_tiny_encoder(weights)
        if net.latent_channels != self.z_dim:
            raise ModelInputError(
                f"tiny encoder: expected {self.z_dim} latent channels (the VAE's z_dim), found {net.latent_channels}"
            )
        if net.time_factor != self.temporal or net.space_factor != self.spatial:
            raise ModelInputError(
                f"tiny encoder: expected /{self.temporal} in time and /{self.spatial} in space (the VAE's), "
                f"found /{net.time_factor} and /{net.space_factor}"
            )
        self.tiny_encoder = TinyVideoEncoder(net, self.mean, self.std, self.device, self.dtype)

    # ------------------------------------------------------------------ shapes
    def latent_shape(self, frames: int, height: int, width: int) -> tuple[int, int, int, int]:
        """(C, T', H', W') of the latent of a (frames, height, width) video; checks 4k+1 and the size."""
        t = check_frame_count(frames, self.temporal)
        if height % self.spatial or width % self.spatial:
            raise ModelInputError(
                f"video size: expected width and height divisible by {self.spatial}, found {width}x{height}"
            )
        return self.z_dim, t, height // self.spatial, width // self.spatial

    @staticmethod
    def to_pixels(frames) -> torch.Tensor:
        """(T, H, W, 3) or (B, T, H, W, 3) uint8 RGB → (B, 3, T, H, W) float32 in [-1, 1]."""
        a = np.asarray(frames)
        if a.dtype != np.uint8 or a.ndim not in (4, 5) or a.shape[-1] != 3:
            raise ModelInputError(
                f"frames: expected (T, H, W, 3) or (B, T, H, W, 3) uint8 RGB, found {a.dtype} {a.shape}"
            )
        if not (a.flags.writeable and a.flags.c_contiguous):
            # torch.from_numpy warns on a read-only array (a frame of a memory map, np.broadcast_to, a view
            # marked read-only): one contiguous, writable copy of the uint8 frames (the float copy follows anyway)
            a = np.array(a, order="C")
        t = torch.from_numpy(a)
        if t.ndim == 4:
            t = t.unsqueeze(0)
        return t.permute(0, 4, 1, 2, 3).float().div(127.5).sub(1.0)

    @staticmethod
    def to_uint8(pixels: torch.Tensor) -> np.ndarray:
        """(B, 3, T, H, W) float in [-1, 1] → (B, T, H, W, 3) uint8 (rounded, clipped)."""
        x = ((pixels.detach().float().clamp(-1, 1) + 1.0) * 127.5).round().to(torch.uint8)
        return x.permute(0, 2, 3, 4, 1).cpu().numpy()

    # ------------------------------------------------------------------ encode / decode
    def _on_device(self):
        if self.offload:
            cast_model(self.vae, self.device)

    def _off_device(self):
        if self.offload:
            cast_model(self.vae, "cpu")

    @torch.no_grad()
    def encode(self, pixels: torch.Tensor) -> torch.Tensor:
        """(B, 3, T, H, W) in [-1, 1], T = 4k+1 → normalised latents (B, z, k+1, H/8, W/8) float32."""
        if pixels.ndim != 5 or pixels.shape[1] != 3:
            raise ModelInputError(f"pixels: expected (B, 3, T, H, W), found shape {tuple(pixels.shape)}")
        self.latent_shape(*pixels.shape[2:])
        self._on_device()
        try:
            dist = self.vae.encode(pixels.to(self.device, self.dtype)).latent_dist
            z = dist.mode().float()
        finally:
            self._off_device()
        return (z - self.mean.to(z.device)) / self.std.to(z.device)

    @torch.no_grad()
    def encode_condition(self, pixels: torch.Tensor) -> torch.Tensor:
        """A condition video's normalised latents, as :meth:`encode`: by the tiny encoder after
        :meth:`use_tiny_encoder`, else by the full encoder (the same call)."""
        if self.tiny_encoder is None:
            return self.encode(pixels)
        if pixels.ndim != 5 or pixels.shape[1] != 3:
            raise ModelInputError(f"pixels: expected (B, 3, T, H, W), found shape {tuple(pixels.shape)}")
        self.latent_shape(*pixels.shape[2:])
        return self.tiny_encoder.encode(pixels)

    @torch.no_grad()
    def decode(self, latents: torch.Tensor) -> torch.Tensor:
        """Normalised latents (B, z, T', H', W') → pixels (B, 3, 4(T'-1)+1, 8H', 8W') float32 in [-1, 1] (by the tiny
        decoder after :meth:`use_tiny_decoder`)."""
        if latents.ndim != 5 or latents.shape[1] != self.z_dim:
            raise ModelInputError(f"latents: expected (B, {self.z_dim}, T, H, W), found shape {tuple(latents.shape)}")
        if self.tiny is not None:
            return self.tiny.decode(latents)
        z = latents.float() * self.std.to(latents.device) + self.mean.to(latents.device)
        self._on_device()
        try:
            out = self.vae.decode(z.to(self.device, self.dtype)).sample
        finally:
            self._off_device()
        return out.float()

    def reconstruct(self, pixels: torch.Tensor) -> torch.Tensor:
        """decode(encode(pixels)): what the VAE makes of a clip (tests and diagnostics)."""
        return self.decode(self.encode(pixels))
