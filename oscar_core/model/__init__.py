"""The OSCAR world model: skeleton-conditioned DiT, VAE wrapper, sampler and rollouts.

Public names are re-exported flat and load on first use (importing diffusers
takes seconds; ``import oscar_core.model`` does not).
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "OscarTransformer3DModel": "transformer",
    "resize_padding_mask": "_resize", "install_torchvision_free_resize": "_resize",
    "VideoVAE": "vae", "check_frame_count": "vae",
    "PromptEmbeddingCache": "text", "empty_prompt_embeds": "text",
    "SamplerConfig": "sampler", "flow_sigmas": "sampler", "guided_velocity": "sampler", "sample_chunk": "sampler",
    "rollout": "rollout", "RolloutResult": "rollout", "chunk_plan": "rollout",
    "OscarWorldModel": "world_model", "ModelCard": "world_model",
    "ModelInputError": "errors", "CheckpointError": "errors", "CheckpointLayoutError": "errors",
    "CheckpointIntegrityError": "errors",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'oscar_core.model' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return __all__
