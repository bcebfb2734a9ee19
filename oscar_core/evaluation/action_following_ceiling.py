"""The autoencoder ceiling of the action-following benchmark: what the best DiT with a model's VAE could score.

A world model's rollout is the VAE's decoding of the latents its DiT predicts, chunk by chunk. If the DiT predicted
every chunk's latent exactly — the VAE's encoding of that chunk's true frames — the rollout would be the VAE's
reconstruction of the true video, assembled as the rollout assembles its chunks
(:func:`oscar_core.model.rollout.reconstruct_rollout`). Scoring that video with the benchmark's judge, locator and
per-chunk metrics gives the ceiling: a verdict the judge cannot give on the reconstruction (the VAE lost the ball)
no DiT with this VAE can give either, so the ceiling's decision accuracy bounds the model's from above (for a judge
of the frames).

The ceiling needs every variant's true frames (the manifest's ``video``; :func:`check_true_videos`, before any model
loads) and only the model's VAE: :func:`load_ceiling_vae` reads the checkpoint's ``vae/`` folder (every layout the
zoo loads has one), never its transformer; it decodes with the decoder a rollout of the same checkpoint would use
(the card's tiny decoder, or the one ``--tiny-decoder`` / ``--full-decoder`` choose).
"""

from __future__ import annotations

import numpy as np

from ..metrics.common import MetricInputError

__all__ = ["CEILING", "ROLLOUT", "check_true_videos", "load_ceiling_vae", "vae_of", "reconstruct_variants"]

#: The mode of a ceiling run, as its report and fingerprint record it.
CEILING = "ceiling: the VAE's reconstruction of the true frames"
#: The mode of an ordinary run.
ROLLOUT = "rollout: the world model's own videos"


def check_true_videos(manifest) -> None:
    """Raise :class:`MetricInputError` naming the manifest and the first variant without a ``video`` (the true
    frames the ceiling reconstructs)."""
    for s in manifest.sets:
        for j, v in enumerate(s.variants):
            if v.video is None:
                raise MetricInputError(
                    manifest.path,
                    f"sets[{s.row}].variants[{j}].video",
                    "the variant's true frames (--ceiling reconstructs them with the model's VAE)",
                    f"no video for variant {v.name!r}",
                )


def load_ceiling_vae(spec: str, revision=None, *, device="cpu", dtype=None, tiny_decoder=None):
    """The :class:`~oscar_core.model.vae.VideoVAE` of checkpoint ``spec`` (zoo name, Hub id or folder), loaded alone:
    the checkpoint is pulled and verified as ``oscar_zoo.load`` does, then only its ``vae/`` folder is read (strict
    safetensors). device, dtype: where and in which dtype the VAE runs (None: float32). tiny_decoder: the decoder,
    chosen as ``OscarWorldModel.from_pretrained`` chooses it (None: the card's ``tiny_decoder`` if it names one, else
    the full decoder; False: the full decoder; a file: that tiny decoder), so the ceiling decodes as the rollout."""
    from pathlib import Path

    import torch

    import oscar_zoo

    from ..model.vae import VideoVAE, load_vae_folder
    from ..model.world_model import MODEL_FILE, read_card

    folder = Path(oscar_zoo.pull(spec, revision))
    if not (folder / "vae").is_dir():
        raise MetricInputError(folder, "vae", "a diffusers vae/ folder (the model's autoencoder)", "no such folder")
    if tiny_decoder is None and (folder / MODEL_FILE).is_file():
        named = read_card(folder).tiny_decoder
        tiny_decoder = folder / named if named is not None else None
    tiny = None
    if tiny_decoder is not None and tiny_decoder is not False:
        from ..model.tiny_decoder import load_tiny_decoder

        tiny = load_tiny_decoder(tiny_decoder)  # checked before the VAE's weights are read
    vae = VideoVAE(load_vae_folder(folder / "vae"), device=device, dtype=dtype or torch.float32)
    if tiny is not None:
        vae.use_tiny_decoder(tiny)
    return vae


def vae_of(model):
    """The VideoVAE of a loaded world model (its ``vae``), or ``model`` itself when it is one (has encode/decode)."""
    if hasattr(model, "encode") and hasattr(model, "decode") and hasattr(model, "temporal"):
        return model
    vae = getattr(model, "vae", None)
    if vae is not None:
        return vae
    raise MetricInputError(
        "model", "vae", "a world model with a VAE (or a VideoVAE) for --ceiling", type(model).__name__
    )


def reconstruct_variants(vae, truths: list, chunk_frames: int, context_frames: int = 1) -> list[np.ndarray]:
    """(T, H, W, 3) uint8 per variant: the VAE's chunk-by-chunk reconstruction of its true frames ``truths[i]``
    ((T, H, W, 3) uint8), chunks of ``chunk_frames`` laid out as the world model's rollout lays them out (chunks
    after the first overlapping by the card's ``context_frames``)."""
    from ..model.rollout import reconstruct_rollout

    return [reconstruct_rollout(vae, t, chunk_frames=chunk_frames, context_frames=context_frames) for t in truths]
