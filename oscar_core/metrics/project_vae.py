"""Latent L2 with the project's own VAE: the WAN 2.1 VAE inside an OSCAR checkpoint.

:func:`load_project_vae` finds a checkpoint through :func:`oscar_zoo.pull`
(zoo name, Hub id or folder) — by default **only in the local cache**, so
evaluating never starts a multi-GB download — builds its ``vae/``
(:class:`oscar_core.model.wan_vae.WanVAE`, diffusers' ``AutoencoderKLWan`` layout, safetensors only, keys matched strictly by
:func:`oscar_core.model.vae.load_vae_folder`) without the DiT, and returns the
encoder :func:`~oscar_core.metrics.video.latent_l2` calls: (1, 3, T, H, W) in
[-1, 1] with T = 4k+1 → normalised latents, exactly what the world model sees
(:class:`oscar_core.model.vae.VideoVAE`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

__all__ = ["DEFAULT_VAE_MODEL", "load_project_vae"]

#: The checkpoint whose VAE ``oscar eval video`` uses for latent L2 when it is in the local cache.
DEFAULT_VAE_MODEL = "oscar-2b"


def load_project_vae(
    spec: str = DEFAULT_VAE_MODEL, revision: str | None = None, *, device="cpu", download: bool = False
) -> Callable:
    """The VAE encoder of checkpoint ``spec`` (see the module docstring); raises if it is not available."""
    import oscar_zoo

    from ..model.vae import VideoVAE, load_vae_folder

    folder = Path(spec) if Path(spec).is_dir() else oscar_zoo.pull(spec, revision, local_files_only=not download)
    vae = load_vae_folder(folder / "vae")  # strict; oscar's own Wan VAE
    wrapped = VideoVAE(vae, device=device)

    def encode(x):
        return wrapped.encode(x)

    encode.source = str(folder)
    return encode
