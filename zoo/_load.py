"""The front door: ``load``, ``pull``, ``export`` and ``push``."""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch

from oscar_core.model._manifest import read_manifest
from oscar_core.model.world_model import MODEL_FILE, ModelCard, OscarWorldModel

from ._fetch import fetch, resolve
from ._registry import register
from ._table import CheckpointSpec

__all__ = ["load", "pull", "export", "push"]


def pull(name_or_repo_or_path, revision: str | None = None, *, cache_dir=None, endpoint=None,
         local_files_only: bool | None = None, force_download: bool = False, token=None, verify: bool = True) -> Path:
    """Download (or find in the cache) and verify a checkpoint; return its local folder.

    name_or_repo_or_path: a zoo name (``oscar_zoo.list_models()``), a Hub id
        ``owner/name`` or a local folder. revision: overrides the pinned one
        (pinned hashes are then not applied). cache_dir: Hub cache (default:
        ``HF_HUB_CACHE`` or huggingface_hub's). endpoint: Hub URL (default:
        ``HF_ENDPOINT`` now, else huggingface.co). local_files_only: None →
        ``HF_HUB_OFFLINE``. force_download: fetch again (after a corruption).
    """
    folder, _ = fetch(resolve(name_or_repo_or_path, revision), cache_dir=cache_dir, endpoint=endpoint,
                      local_files_only=local_files_only, force_download=force_download, token=token, verify=verify)
    return folder


def load(name_or_repo_or_path, revision: str | None = None, device="cpu", dtype: torch.dtype | None = None, *,
         vae_dtype: torch.dtype | None = None, offload_vae: bool = False, offload_text: bool = False,
         cache_dir=None, endpoint=None,
         local_files_only: bool | None = None, force_download: bool = False, token=None,
         verify: bool = True) -> OscarWorldModel:
    """Load a world model by zoo name, Hub id or folder (arguments as :func:`pull`).

    Safetensors only, never ``trust_remote_code``, never unpickles; sha256
    checked where known (table, user registry, the checkpoint's manifest);
    every weight file's structure checked (partial files are reported, not
    loaded). Hashing reads every file once per load (~10 s for the 2B
    model's ~4.5 GB); ``verify=False`` skips it for a cache you trust. A ``cosmos-base`` checkpoint loads as an OSCAR model whose
    skeleton embedder is zero (the base model exactly).
    device, dtype: where and in which dtype the DiT runs (bf16 on GPUs);
    vae_dtype: the VAE's (default: dtype); offload_vae: keep the VAE on the
    CPU between encode/decode calls; offload_text: keep the DiT's text
    projection on the CPU (see ``OscarWorldModel.from_modules``).
    """
    resolved = resolve(name_or_repo_or_path, revision)
    folder, kind = fetch(resolved, cache_dir=cache_dir, endpoint=endpoint, local_files_only=local_files_only,
                         force_download=force_download, token=token, verify=verify)
    options = dict(device=device, dtype=dtype, vae_dtype=vae_dtype, offload_vae=offload_vae, offload_text=offload_text)
    if kind == "cosmos-base":
        return OscarWorldModel.from_cosmos_base(folder, _card_from_spec(resolved.spec), **options)
    return OscarWorldModel.from_pretrained(folder, verify=False, **options)  # fetch() verified it


def _card_from_spec(spec: CheckpointSpec | None) -> ModelCard:
    if spec is None:
        return ModelCard(name="cosmos-base")
    base = f"{spec.repo_id}@{spec.revision or 'main'}"
    return ModelCard(name=spec.name, chunk_frames=spec.chunk_frames or 81, width=spec.width, height=spec.height,
                     fps=spec.fps, embodiments=spec.embodiments, text_encoder_id=spec.text_encoder_id, base=base,
                     license=spec.license)


def export(model: OscarWorldModel, folder, card: ModelCard | None = None) -> Path:
    """Write ``model`` as an OSCAR folder (safetensors + card + sha256 manifest), ready to push or load."""
    return model.save_pretrained(folder, card)


def push(folder, repo_id: str, *, name: str | None = None, private: bool | None = None, token=None,
         endpoint=None, commit_message: str = "Upload OSCAR world model", overwrite: bool = False):
    """Upload an exported folder to the Hub; with ``name``, register it so ``load(name)`` finds it.

    The registry entry pins the commit the upload created and the sha256 of
    every file (from the folder's manifest). Returns the CheckpointSpec when
    ``name`` is given, else the commit hash.
    """
    from huggingface_hub import HfApi

    folder = Path(folder)
    manifest = read_manifest(folder)
    if manifest is None or not (folder / MODEL_FILE).is_file():
        raise ValueError(f"{folder}: expected a folder written by oscar_zoo.export (with {MODEL_FILE} and a "
                         f"manifest), found {sorted(p.name for p in folder.iterdir()) if folder.is_dir() else 'none'}")
    api = HfApi(endpoint=endpoint or os.environ.get("HF_ENDPOINT") or None, token=token)
    api.create_repo(repo_id, private=private, exist_ok=True)
    info = api.upload_folder(folder_path=str(folder), repo_id=repo_id, commit_message=commit_message)
    commit = getattr(info, "oid", None)
    if name is None:
        return commit
    card = json.loads((folder / MODEL_FILE).read_text()).get("card", {})
    fields = {k: card.get(k) for k in ("license", "embodiments", "chunk_frames", "width", "height", "fps",
                                       "text_encoder_id")}
    files = {path: meta.get("sha256") for path, meta in manifest.items()}
    return register(name, repo_id, commit, kind="oscar", files=files, overwrite=overwrite, **fields)
