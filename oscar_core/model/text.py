"""Prompt embeddings: precomputed, cached on disk, or the empty-prompt fallback.

The 2B model cross-attends to Cosmos-Reason1 (Qwen2.5-VL-7B) features: the
hidden states of all its layers, each normalised, concatenated to 100352
values per token, 512 tokens (diffusers' ``Cosmos2_5_PredictBasePipeline.
_get_prompt_embeds``). Running a 7B encoder for every rollout is wasteful, so
oscar takes a precomputed embedding (1, L, D) and keeps a cache of them:

* :class:`PromptEmbeddingCache` stores one safetensors file per prompt,
  named by sha256(encoder id + "\\n" + prompt), so the same prompt embedded
  by two different encoders never collides. The prompt and encoder id are
  kept in the file's metadata and checked on read.
* :func:`empty_prompt_embeds` is the fallback when no text is given: a
  checkpoint's stored empty-prompt embedding when it ships one
  (``OscarWorldModel.empty_prompt_embeds``), else zeros of shape (1, L, D)
  with D the model's text dimension. With identical (zero) tokens,
  cross-attention returns the same value for every sequence length L, so L
  = 1 is used by default; it is *not* the encoder's embedding of "" — for
  fidelity to a trained model, store that once in the cache under "".
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from .._util.atomic import atomic_output
from .errors import CheckpointIntegrityError, ModelInputError

__all__ = ["PromptEmbeddingCache", "empty_prompt_embeds", "prompt_key", "default_cache_dir", "check_prompt_embeds"]

_TENSOR = "prompt_embeds"


def default_cache_dir() -> Path:
    """``$OSCAR_CACHE/prompt_embeds``, else ``$XDG_CACHE_HOME/oscar/prompt_embeds`` (``~/.cache/...``)."""
    root = os.environ.get("OSCAR_CACHE")
    if root:
        return Path(root) / "prompt_embeds"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "oscar" / "prompt_embeds"


def prompt_key(prompt: str, encoder_id: str) -> str:
    """Hex sha256 of ``encoder_id + "\\n" + prompt`` (the cache file's name)."""
    return hashlib.sha256(f"{encoder_id}\n{prompt}".encode()).hexdigest()


def check_prompt_embeds(embeds: torch.Tensor, dim: int, source: str = "prompt_embeds") -> torch.Tensor:
    """(L, D) or (B, L, D) with D = ``dim`` → (B, L, D); raises ModelInputError otherwise."""
    if not isinstance(embeds, torch.Tensor) or embeds.ndim not in (2, 3):
        found = f"{type(embeds).__name__} {tuple(getattr(embeds, 'shape', ()))}"
        raise ModelInputError(f"{source}: expected a (L, {dim}) or (B, L, {dim}) tensor, found {found}")
    if embeds.ndim == 2:
        embeds = embeds.unsqueeze(0)
    if embeds.shape[-1] != dim or embeds.shape[1] < 1:
        raise ModelInputError(
            f"{source}: expected last dimension {dim} (the model's text dimension) and L >= 1, "
            f"found shape {tuple(embeds.shape)}"
        )
    return embeds


def empty_prompt_embeds(dim: int, seq_len: int = 1, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Zero prompt embedding (1, seq_len, dim): the documented no-text fallback."""
    return torch.zeros(1, seq_len, dim, dtype=dtype)


class PromptEmbeddingCache:
    """A folder of prompt embeddings, one safetensors file per (encoder, prompt).

    root: folder (default :func:`default_cache_dir`); encoder_id: names the
    text encoder and its revision, e.g.
    ``"nvidia/Cosmos-Predict2.5-2B@diffusers/base/post-trained:text_encoder"``.
    """

    def __init__(self, root=None, encoder_id: str = "unknown-encoder"):
        self.root = Path(root) if root is not None else default_cache_dir()
        self.encoder_id = encoder_id

    def path(self, prompt: str) -> Path:
        return self.root / f"{prompt_key(prompt, self.encoder_id)}.safetensors"

    def __contains__(self, prompt: str) -> bool:
        return self.path(prompt).is_file()

    def get(self, prompt: str) -> torch.Tensor | None:
        """The cached (1, L, D) embedding of ``prompt``, or None when absent."""
        path = self.path(prompt)
        if not path.is_file():
            return None
        try:
            from safetensors import safe_open

            with safe_open(str(path), framework="pt") as fh:
                meta = fh.metadata() or {}
            tensors = load_file(str(path))
        except (SafetensorError, OSError, ValueError) as exc:
            raise CheckpointIntegrityError(
                path,
                "prompt embedding file",
                "a readable safetensors file",
                f"an unreadable file ({exc})",
                "delete it to recompute",
            ) from None
        if meta.get("prompt") != prompt or meta.get("encoder_id") != self.encoder_id or _TENSOR not in tensors:
            raise CheckpointIntegrityError(
                path,
                "metadata",
                f"prompt {prompt!r} by encoder {self.encoder_id!r}",
                f"prompt {meta.get('prompt')!r} by encoder {meta.get('encoder_id')!r}",
            )
        return tensors[_TENSOR]

    def put(self, prompt: str, embeds: torch.Tensor) -> Path:
        """Store ``embeds`` ((L, D) or (1, L, D)) for ``prompt``; returns the file written (atomically)."""
        embeds = check_prompt_embeds(embeds, int(embeds.shape[-1]), f"embedding of {prompt!r}")
        if embeds.shape[0] != 1:
            raise ModelInputError(f"embedding of {prompt!r}: expected batch 1, found shape {tuple(embeds.shape)}")
        path = self.path(prompt)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(path) as tmp:
            save_file(
                {_TENSOR: embeds.detach().cpu().contiguous()},
                str(tmp),
                metadata={"prompt": prompt, "encoder_id": self.encoder_id},
            )
        return path

    def get_or_encode(self, prompt: str, encode) -> torch.Tensor:
        """Cached embedding of ``prompt``, computing and storing ``encode(prompt)`` on a miss."""
        cached = self.get(prompt)
        if cached is not None:
            return cached
        embeds = encode(prompt)
        self.put(prompt, embeds)
        return self.get(prompt)
