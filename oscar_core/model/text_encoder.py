"""The Cosmos-Reason1 prompt embedding, computed the way diffusers' Cosmos-Predict2.5 pipeline does.

``Cosmos2_5_PredictBasePipeline._get_prompt_embeds`` (diffusers 0.42) does,
per prompt:

1. a chat of two turns — system: "You are a helpful assistant who will
   provide prompts to an image generator.", user: the prompt — through the
   tokenizer's chat template (``add_generation_prompt=False``,
   ``add_vision_id=False``), truncated and padded to 512 tokens;
2. one forward of the Qwen2.5-VL text encoder with ``output_hidden_states``;
3. every hidden state after the embedding layer (``hidden_states[1:]``, one
   per decoder layer) normalised over its feature axis, (h − mean) /
   (std + 1e-8) with torch's default (unbiased) std, and the results
   concatenated along the features: 28 layers × 3584 = 100352 values per
   token for Cosmos-Reason1-7B.

:func:`encode_prompts` repeats exactly that (a test compares it with the
pipeline's own method on a tiny random Qwen2.5-VL). :class:`TextEncoder`
loads the encoder + tokenizer (safetensors only) from a diffusers pipeline
folder or Hub repo (``text_encoder/`` and ``tokenizer/``) and keeps the
embeddings in a :class:`~oscar_core.model.text.PromptEmbeddingCache` keyed by
prompt and encoder id (repo, revision and commit), so each prompt runs
through the 7B encoder once.

transformers is an optional dependency: ``pip install "oscar-wm[text]"``.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import torch

from .errors import CheckpointLayoutError, ModelInputError

__all__ = [
    "SYSTEM_PROMPT",
    "MAX_SEQUENCE_LENGTH",
    "require_transformers",
    "chat",
    "prompt_input_ids",
    "embed_hidden_states",
    "encode_prompts",
    "TextEncoder",
    "parse_encoder_id",
]

SYSTEM_PROMPT = "You are a helpful assistant who will provide prompts to an image generator."
MAX_SEQUENCE_LENGTH = 512
_NORM_EPS = 1e-8


def require_transformers():
    """Import transformers or raise ImportError naming the extra to install (the one availability check)."""
    try:
        import transformers
    except ImportError as exc:
        raise ImportError('computing prompt embeddings needs transformers: pip install "oscar-wm[text]"') from exc
    return transformers


def chat(prompt: str) -> list[dict]:
    """The two-turn conversation the Cosmos 2.5 pipeline feeds the chat template."""
    return [
        {"role": "system", "content": [{"type": "text", "text": SYSTEM_PROMPT}]},
        {"role": "user", "content": [{"type": "text", "text": prompt}]},
    ]


def prompt_input_ids(tokenizer, prompts: list[str], max_length: int = MAX_SEQUENCE_LENGTH) -> torch.Tensor:
    """(B, max_length) int64 token ids: chat template, truncated and padded to ``max_length``."""
    rows = []
    for prompt in prompts:
        if not isinstance(prompt, str):
            raise ModelInputError(f"prompt: expected a string, found {type(prompt).__name__}")
        ids = tokenizer.apply_chat_template(
            chat(prompt),
            tokenize=True,
            add_generation_prompt=False,
            add_vision_id=False,
            max_length=max_length,
            truncation=True,
            padding="max_length",
        )
        if not isinstance(ids, list) and "input_ids" in ids:
            ids = ids["input_ids"]
        rows.append(torch.as_tensor(ids, dtype=torch.long))
    return torch.stack(rows)


def embed_hidden_states(hidden_states) -> torch.Tensor:
    """Per-layer normalised hidden states (layers 1..N of ``hidden_states``) concatenated: (B, L, N·hidden)."""
    parts = []
    for h in hidden_states[1:]:
        parts.append((h - h.mean(dim=-1, keepdim=True)) / (h.std(dim=-1, keepdim=True) + _NORM_EPS))
    return torch.cat(parts, dim=-1)


@torch.no_grad()
def encode_prompts(
    text_encoder,
    tokenizer,
    prompts: str | list[str],
    *,
    max_length: int = MAX_SEQUENCE_LENGTH,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    """(B, max_length, layers × hidden) prompt embeddings, as diffusers' Cosmos 2.5 pipeline computes them.

    text_encoder: a transformers ``Qwen2_5_VLForConditionalGeneration`` (any
    size); tokenizer: its tokenizer (with a chat template); dtype: of the
    result (default: the encoder's).
    """
    prompts = [prompts] if isinstance(prompts, str) else list(prompts)
    device = next(text_encoder.parameters()).device
    ids = prompt_input_ids(tokenizer, prompts, max_length)
    out = text_encoder(ids.to(device), output_hidden_states=True)
    return embed_hidden_states(out.hidden_states).to(dtype or text_encoder.dtype)


def parse_encoder_id(encoder_id: str) -> tuple[str, str | None, str]:
    """``"owner/name@revision:text_encoder"`` → (repo or folder, revision or None, subfolder)."""
    source, _, sub = encoder_id.rpartition(":") if ":" in encoder_id.split("@")[-1] else (encoder_id, "", "")
    repo, _, revision = source.partition("@")
    return repo, (revision or None), (sub or "text_encoder")


class TextEncoder:
    """A Qwen2.5-VL text encoder + tokenizer and the prompt-embedding cache keyed by its id.

    model, tokenizer: transformers objects; encoder_id: the cache key prefix
    (repo@commit:subfolder, or a folder and the sha256 of its config).
    """

    def __init__(self, model, tokenizer, encoder_id: str, max_length: int = MAX_SEQUENCE_LENGTH):
        self.model, self.tokenizer, self.encoder_id, self.max_length = model, tokenizer, encoder_id, max_length

    @classmethod
    def from_folder(
        cls,
        folder,
        *,
        encoder_id: str | None = None,
        subfolder: str = "text_encoder",
        device="cpu",
        dtype: torch.dtype | None = None,
    ) -> TextEncoder:
        """Load ``folder/text_encoder`` (safetensors only) and ``folder/tokenizer`` (a diffusers pipeline folder)."""
        transformers = require_transformers()
        folder = Path(folder)
        enc_dir, tok_dir = folder / subfolder, folder / "tokenizer"
        for need in (enc_dir / "config.json", tok_dir):
            if not need.exists():
                found = ", ".join(sorted(p.name for p in folder.iterdir())) if folder.is_dir() else "no such folder"
                raise CheckpointLayoutError(
                    folder,
                    "text encoder",
                    f"{subfolder}/config.json + safetensors weights "
                    "and tokenizer/ (a diffusers Cosmos-Predict2.5 folder)",
                    found,
                )
        if not any(enc_dir.glob("*.safetensors")):
            raise CheckpointLayoutError(
                enc_dir,
                "weights",
                "safetensors files (pickles are never loaded)",
                ", ".join(sorted(p.name for p in enc_dir.iterdir())),
            )
        model = (
            transformers.Qwen2_5_VLForConditionalGeneration.from_pretrained(
                str(enc_dir), use_safetensors=True, dtype=dtype or "auto"
            )
            .to(device)
            .eval()
        )
        tokenizer = transformers.AutoTokenizer.from_pretrained(str(tok_dir))
        if encoder_id is None:
            digest = hashlib.sha256((enc_dir / "config.json").read_bytes()).hexdigest()[:16]
            encoder_id = f"{folder.resolve()}#{digest}:{subfolder}"
        return cls(model, tokenizer, encoder_id)

    @classmethod
    def from_hub(
        cls,
        encoder_id: str,
        *,
        cache_dir=None,
        endpoint=None,
        local_files_only: bool | None = None,
        token=None,
        device="cpu",
        dtype: torch.dtype | None = None,
    ) -> TextEncoder:
        """Download ``text_encoder/`` and ``tokenizer/`` of ``encoder_id``'s repo (safetensors, JSON, text only)."""
        require_transformers()
        from oscar_zoo._fetch import hub_snapshot

        repo, revision, sub = parse_encoder_id(encoder_id)
        if Path(repo).expanduser().is_dir():
            return cls.from_folder(
                Path(repo).expanduser(), encoder_id=encoder_id, subfolder=sub, device=device, dtype=dtype
            )
        root, _commit = hub_snapshot(
            repo,
            revision,
            [f"{sub}/*.json", f"{sub}/*.safetensors", "tokenizer/*"],
            cache_dir=cache_dir,
            endpoint=endpoint,
            local_files_only=local_files_only,
            token=token,
        )
        return cls.from_folder(root, encoder_id=encoder_id, subfolder=sub, device=device, dtype=dtype)

    @property
    def text_dim(self) -> int:
        """Features per token of the embedding: decoder layers × hidden size."""
        cfg = self.model.config
        text = getattr(cfg, "text_config", cfg)
        return int(text.num_hidden_layers) * int(text.hidden_size)

    def encode(self, prompt: str) -> torch.Tensor:
        """(1, L, text_dim) float32 embedding of one prompt (no cache)."""
        return encode_prompts(self.model, self.tokenizer, prompt, max_length=self.max_length).float().cpu()

    def cached(self, prompt: str, cache_dir=None) -> tuple[torch.Tensor, bool]:
        """(embedding, was_cached): from the cache, else computed and stored there."""
        from .text import PromptEmbeddingCache

        cache = PromptEmbeddingCache(cache_dir, encoder_id=self.encoder_id)
        found = cache.get(prompt)
        if found is not None:
            return found, True
        return cache.get_or_encode(prompt, self.encode), False

    def describe(self) -> str:
        return json.dumps({"encoder_id": self.encoder_id, "text_dim": self.text_dim})
