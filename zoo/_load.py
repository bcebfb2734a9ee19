"""The front door: ``load``, ``pull``, ``export`` and ``push``."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

from oscar_core.model._files import MODEL_FILE
from oscar_core.model.manifest import read_manifest

from ._fetch import fetch, is_offline, resolve
from ._registry import register
from ._table import COSMOS_TEXT_ENCODER_ID, CheckpointSpec

if TYPE_CHECKING:  # torch and diffusers load with the model, not with `oscar zoo list` / `pull`
    import torch

    from oscar_core.model.world_model import ModelCard, OscarWorldModel

__all__ = ["load", "pull", "export", "push", "convert"]


def pull(
    name_or_repo_or_path,
    revision: str | None = None,
    *,
    cache_dir=None,
    endpoint=None,
    local_files_only: bool | None = None,
    force_download: bool = False,
    token=None,
    verify: bool = True,
    native_file: str | None = None,
) -> Path:
    """Download (or find in the cache) and verify a checkpoint; return its local folder.

    Online, a pull resolves the revision anew and records the commit and the
    sha256 of every file in a lock file beside the cache; later loads use
    that commit and check the files against it.

    name_or_repo_or_path: a zoo name (``oscar_zoo.list_models()``), a Hub id
        ``owner/name`` or a local folder. revision: overrides the pinned one
        (pinned hashes are then not applied). cache_dir: Hub cache (default:
        ``HF_HUB_CACHE`` or huggingface_hub's). endpoint: Hub URL (default:
        ``HF_ENDPOINT`` now, else huggingface.co). local_files_only: None →
        ``HF_HUB_OFFLINE``. force_download: fetch again (after a corruption).
    """
    got = fetch(
        resolve(name_or_repo_or_path, revision),
        cache_dir=cache_dir,
        endpoint=endpoint,
        local_files_only=local_files_only,
        force_download=force_download,
        token=token,
        verify=verify,
        native_file=native_file,
        update_lock=not is_offline(local_files_only),
    )
    return got.folder


def load(
    name_or_repo_or_path,
    revision: str | None = None,
    device="cpu",
    dtype: torch.dtype | None = None,
    *,
    vae_dtype: torch.dtype | None = None,
    offload_vae: bool = False,
    offload_text: bool = False,
    cache_dir=None,
    endpoint=None,
    local_files_only: bool | None = None,
    force_download: bool = False,
    token=None,
    verify: bool = True,
    native_file: str | None = None,
    report: list | None = None,
    tiny_decoder=None,
    tiny_encoder=None,
) -> OscarWorldModel:
    """Load a world model by zoo name, Hub id or folder (arguments as :func:`pull`).

    Safetensors only, never ``trust_remote_code``, never unpickles; sha256
    checked where known (table, user registry, the checkpoint's manifest);
    every weight file's structure checked (partial files are reported, not
    loaded). Each file is hashed once, and its digest is remembered with the
    file's size, times, inode and device (``$OSCAR_CACHE/verified``): a later
    load of an unchanged file does not read it again (``OSCAR_VERIFY=full``
    always hashes; ~0.65 s per GB on a CPU core); ``verify=False`` skips the
    check for a cache you trust. A ``cosmos-base`` checkpoint loads as an OSCAR model whose
    skeleton embedder is zero (the base model exactly).
    device, dtype: where and in which dtype the DiT runs (bf16 on GPUs);
    vae_dtype: the VAE's (default: dtype); offload_vae: keep the VAE on the
    CPU between encode/decode calls; offload_text: keep the DiT's text
    projection on the CPU (see ``OscarWorldModel.from_modules``).
    tiny_decoder: a tiny decoder's safetensors file to decode with instead of the full VAE decoder; None: the
    card's choice (its ``tiny_decoder``, else the full decoder); False: the full decoder
    (``OscarWorldModel.from_pretrained``).
    tiny_encoder: a tiny encoder's safetensors file to encode the condition videos with instead of the full VAE
    encoder; None or False: the full encoder (``OscarWorldModel.from_pretrained``).
    """
    from oscar_core._util.devices import check_device
    from oscar_core.model.errors import ModelInputError
    from oscar_core.model.layouts import load_folder

    check_device(device, ModelInputError)  # before resolving or downloading anything
    resolved = resolve(name_or_repo_or_path, revision)
    got = fetch(
        resolved,
        cache_dir=cache_dir,
        endpoint=endpoint,
        local_files_only=local_files_only,
        force_download=force_download,
        token=token,
        verify=verify,
        native_file=native_file,
    )
    options = dict(device=device, dtype=dtype, vae_dtype=vae_dtype, offload_vae=offload_vae, offload_text=offload_text)
    if tiny_decoder is not None:
        options["tiny_decoder"] = tiny_decoder
    if tiny_encoder is not None:
        options["tiny_encoder"] = tiny_encoder
    card = None if got.layout.kind == "oscar" else _card_from_spec(resolved.spec)
    model, layout = load_folder(got.folder, got.layout, card, verify=False, **options)  # fetch() verified it
    if report is not None:
        report.extend(layout.report)
    return model


def _card_from_spec(spec: CheckpointSpec | None) -> ModelCard:
    from oscar_core.model.world_model import ModelCard

    if spec is None:
        return ModelCard(name="cosmos-base", text_encoder_id=COSMOS_TEXT_ENCODER_ID)
    base = f"{spec.repo_id}@{spec.revision or 'main'}"
    return ModelCard(
        name=spec.name,
        chunk_frames=spec.chunk_frames or 81,
        width=spec.width,
        height=spec.height,
        fps=spec.fps,
        embodiments=spec.embodiments,
        text_encoder_id=spec.text_encoder_id,
        base=base,
        license=spec.license,
    )


def convert(
    src,
    dst,
    *,
    revision: str | None = None,
    native_file: str | None = None,
    card: ModelCard | None = None,
    report: list | None = None,
    **fetch_options,
) -> Path:
    """Load ``src`` in any layout (zoo name, Hub id or folder) and write it to ``dst`` in oscar's layout.

    The weights keep their stored dtype; the scheduler config (if any) is
    kept. Returns ``dst``. ``report`` receives what the loader found.
    """
    model = load(src, revision, native_file=native_file, report=report, **fetch_options)
    return model.save_pretrained(dst, card)


def export(model: OscarWorldModel, folder, card: ModelCard | None = None) -> Path:
    """Write ``model`` as an OSCAR folder (safetensors + card + sha256 manifest), ready to push or load."""
    return model.save_pretrained(folder, card)


def push(
    folder,
    repo_id: str,
    *,
    name: str | None = None,
    private: bool | None = None,
    token=None,
    endpoint=None,
    commit_message: str = "Upload OSCAR world model",
    overwrite: bool = False,
):
    """Upload an exported folder to the Hub; with ``name``, register it so ``load(name)`` finds it.

    The registry entry pins the commit the upload created and the sha256 of
    every file (from the folder's manifest). Returns the CheckpointSpec when
    ``name`` is given, else the commit hash.
    """
    from huggingface_hub import HfApi

    folder = Path(folder)
    manifest = read_manifest(folder)
    if manifest is None or not (folder / MODEL_FILE).is_file():
        raise ValueError(
            f"{folder}: expected a folder written by oscar_zoo.export (with {MODEL_FILE} and a "
            f"manifest), found {sorted(p.name for p in folder.iterdir()) if folder.is_dir() else 'none'}"
        )
    api = HfApi(endpoint=endpoint or os.environ.get("HF_ENDPOINT") or None, token=token)
    api.create_repo(repo_id, private=private, exist_ok=True)
    info = api.upload_folder(folder_path=str(folder), repo_id=repo_id, commit_message=commit_message)
    commit = getattr(info, "oid", None)
    if name is None:
        return commit
    card = json.loads((folder / MODEL_FILE).read_text()).get("card", {})
    fields = {
        k: card.get(k) for k in ("license", "embodiments", "chunk_frames", "width", "height", "fps", "text_encoder_id")
    }
    files = {path: meta.get("sha256") for path, meta in manifest.items()}
    return register(name, repo_id, commit, kind="oscar", files=files, overwrite=overwrite, **fields)
