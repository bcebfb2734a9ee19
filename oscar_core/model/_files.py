"""File names of oscar's model folder layout, importable without torch (``oscar zoo list`` / ``pull`` read them)."""

from __future__ import annotations

__all__ = ["MODEL_FILE", "EMPTY_PROMPT_FILE", "SCHEDULER_FILE"]

#: The card and format marker of a model folder (``OscarWorldModel.save_pretrained``).
MODEL_FILE = "oscar_model.json"
#: The empty prompt's embedding (the unconditional text input), optional in a folder.
EMPTY_PROMPT_FILE = "text/empty_prompt_embeds.safetensors"
#: The sampler's scheduler config, optional in a folder.
SCHEDULER_FILE = "scheduler/scheduler_config.json"
