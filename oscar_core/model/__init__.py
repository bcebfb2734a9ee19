"""The OSCAR world model: skeleton-conditioned DiT, VAE wrapper, sampler and rollouts.

Public names are re-exported flat and load on first use (importing diffusers
takes seconds; ``import oscar_core.model`` does not).
"""

from __future__ import annotations

from .._util.lazy import lazy_exports

_EXPORTS = {
    "OscarTransformer3DModel": "transformer",
    "resize_padding_mask": "_resize",
    "install_torchvision_free_resize": "_resize",
    "VideoVAE": "vae",
    "check_frame_count": "chunks",
    "load_vae_folder": "vae",
    "PromptEmbeddingCache": "text",
    "empty_prompt_embeds": "text",
    "SamplerConfig": "sampler",
    "flow_sigmas": "sampler",
    "guided_velocity": "sampler",
    "sample_chunk": "sampler",
    "rollout": "rollout",
    "RolloutResult": "rollout",
    "chunk_plan": "chunks",
    "chunk_windows": "chunks",
    "iter_rollout": "rollout",
    "reconstruct_rollout": "rollout",
    "integrate": "sampler",
    "unipc_scheduler": "sampler",
    "TextEncoder": "text_encoder",
    "encode_prompts": "text_encoder",
    "detect_layout": "layouts",
    "load_folder": "layouts",
    "LAYOUTS": "layouts",
    "LatentActionTransformer": "latent_action",
    "latent_actions": "latent_action",
    "OscarWorldModel": "world_model",
    "ModelCard": "world_model",
    "RolloutRequest": "rollout_files",
    "RolloutFilesResult": "rollout_files",
    "run_rollout": "rollout_files",
    "ModelInputError": "errors",
    "CheckpointError": "errors",
    "CheckpointLayoutError": "errors",
    "CheckpointIntegrityError": "errors",
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
