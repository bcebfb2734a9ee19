"""Resolve a name / Hub id / folder, download what the layout needs, and verify it.

Downloads go through ``huggingface_hub.hf_hub_download`` one file at a time
(the file list follows from the layout: configs, then a single safetensors
file or an index and its shards), into the standard Hub cache, so a second
load — or one with ``HF_HUB_OFFLINE=1`` — reads the cache. Only safetensors
and JSON files are ever requested.

``HF_ENDPOINT`` and ``HF_HUB_OFFLINE`` are read when a function is called
(huggingface_hub itself reads them once, at import), and passed on
explicitly; ``endpoint=`` / ``local_files_only=`` arguments override them.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from oscar_core.errors import OscarError
from oscar_core.model._manifest import MANIFEST_NAME, read_manifest, verify_files
from oscar_core.model._weights import INDEX_NAME, WEIGHTS_NAME, check_safetensors
from oscar_core.model.errors import CheckpointIntegrityError, CheckpointLayoutError
from oscar_core.model.world_model import EMPTY_PROMPT_FILE, MODEL_FILE

from ._registry import user_models
from ._table import CHECKPOINTS, CheckpointSpec

__all__ = ["UnknownModelError", "Resolved", "resolve", "fetch", "list_models", "local_kind", "is_offline",
           "OSCAR_LAYOUT"]

OSCAR_LAYOUT = (MODEL_FILE, "transformer/config.json", f"transformer/{WEIGHTS_NAME} (or an index + shards)",
                "vae/config.json", f"vae/{WEIGHTS_NAME}", f"{MANIFEST_NAME} (optional)", f"{EMPTY_PROMPT_FILE} (optional)")
_PICKLES = (".bin", ".pt", ".pth", ".ckpt", ".pkl")


class UnknownModelError(OscarError, ValueError):
    """A name that is neither in the zoo, nor a Hub repo id, nor a folder."""


def list_models() -> tuple[CheckpointSpec, ...]:
    """The built-in table and the user registry, sorted by name."""
    return tuple(sorted(CHECKPOINTS + user_models(), key=lambda s: s.name))


def is_offline(local_files_only: bool | None = None) -> bool:
    """``local_files_only`` if given, else ``HF_HUB_OFFLINE`` as set now (or at huggingface_hub's import)."""
    if local_files_only is not None:
        return bool(local_files_only)
    value = os.environ.get("HF_HUB_OFFLINE")
    if value is not None:
        return value.strip().upper() in ("1", "ON", "YES", "TRUE")
    from huggingface_hub import constants

    return bool(constants.HF_HUB_OFFLINE)


@dataclass(frozen=True)
class Resolved:
    """Where a checkpoint comes from: a spec (table, registry or ad-hoc repo id) or a local folder."""

    label: str
    spec: CheckpointSpec | None = None
    folder: Path | None = None

    @property
    def revision(self) -> str:
        return (self.spec.revision if self.spec else None) or "main"


def resolve(name_or_repo_or_path, revision: str | None = None) -> Resolved:
    """A local folder, a zoo name (table or user registry) or a Hub ``owner/name``, in that order."""
    text = str(name_or_repo_or_path)
    path = Path(text).expanduser()
    if path.is_dir():
        return Resolved(str(path), folder=path)
    for spec in list_models():
        if spec.name == text:
            if revision is not None:
                spec = _replace_revision(spec, revision)
            return Resolved(f"{spec.name} ({spec.repo_id}@{spec.revision or 'main'})", spec=spec)
    if text.count("/") == 1 and all(text.split("/")) and not text.startswith((".", "/", "~")):
        for spec in list_models():  # a known repo id gets its table entry (hashes, kind, card)
            if spec.repo_id == text:
                if revision is not None:
                    spec = _replace_revision(spec, revision)
                return Resolved(f"{spec.name} ({text}@{spec.revision or 'main'})", spec=spec)
        spec = CheckpointSpec(name=text, repo_id=text, revision=revision, kind="oscar", license=None, paper=None,
                              source="hub id")
        return Resolved(f"{text}@{revision or 'main'}", spec=spec)
    known = ", ".join(s.name for s in list_models())
    raise UnknownModelError(f"model {text!r}: expected a zoo name ({known}), a Hub repo id 'owner/name' or an "
                            f"existing folder, found none of these")


def _replace_revision(spec: CheckpointSpec, revision: str) -> CheckpointSpec:
    from dataclasses import replace

    # hashes pinned for another revision do not apply to this one
    files = spec.files if revision == spec.revision else tuple(type(f)(f.path, None) for f in spec.files)
    return replace(spec, revision=revision, files=files)


def local_kind(folder: Path) -> str:
    """"oscar" or "cosmos-base" for a local folder, from the files it holds."""
    if (folder / MODEL_FILE).is_file():
        return "oscar"
    config = folder / "transformer" / "config.json"
    if config.is_file():
        try:
            name = json.loads(config.read_text()).get("_class_name")
        except ValueError:
            name = None
        if name == "CosmosTransformer3DModel":
            return "cosmos-base"
    found = ", ".join(sorted(p.relative_to(folder).as_posix() for p in folder.iterdir())) or "an empty folder"
    raise CheckpointLayoutError(folder, "files", f"an OSCAR model folder ({', '.join(OSCAR_LAYOUT)}) or a diffusers "
                                f"Cosmos-Predict2.5 folder (transformer/, vae/)", found)


class _Fetcher:
    """hf_hub_download with oscar's error messages; remembers the snapshot folder and what was missing."""

    def __init__(self, resolved: Resolved, cache_dir, endpoint, offline: bool, force: bool, token):
        self.r, self.spec = resolved, resolved.spec
        self.cache_dir = str(cache_dir) if cache_dir is not None else (os.environ.get("HF_HUB_CACHE") or None)
        self.endpoint = endpoint or os.environ.get("HF_ENDPOINT") or None
        self.offline, self.force, self.token = offline, force, token
        self.root: Path | None = None
        self.got: list[str] = []
        self.missing: list[str] = []

    def get(self, path: str, required: bool = True) -> Path | None:
        from huggingface_hub import hf_hub_download
        from huggingface_hub.errors import (EntryNotFoundError, GatedRepoError, LocalEntryNotFoundError,
                                            RepositoryNotFoundError, RevisionNotFoundError)

        if path in self.got:
            return self.root / path
        try:
            local = hf_hub_download(self.spec.repo_id, path, revision=self.r.revision, cache_dir=self.cache_dir,
                                    endpoint=self.endpoint, local_files_only=self.offline,
                                    force_download=self.force and not self.offline, token=self.token)
        except RevisionNotFoundError:
            raise CheckpointLayoutError(self.r.label, "revision", f"a branch, tag or commit of {self.spec.repo_id}",
                                        f"no revision {self.r.revision!r}") from None
        except (RepositoryNotFoundError, GatedRepoError) as exc:
            raise CheckpointLayoutError(self.r.label, "repository", f"an accessible Hub repository {self.spec.repo_id}",
                                        f"{type(exc).__name__}", "check the id, your token and the endpoint "
                                        f"({self.endpoint or 'huggingface.co'})") from None
        except (LocalEntryNotFoundError, EntryNotFoundError):
            if required:
                self.missing.append(path)
            return None
        except OSError as exc:  # e.g. huggingface_hub's size "consistency check failed" on a partial download
            raise CheckpointIntegrityError(f"{self.r.label}: {path}", "download", "a complete file",
                                           f"{type(exc).__name__}: {exc}") from None
        local = Path(local)
        root = Path(str(local)[: -len(path)])
        if self.root is None:
            self.root = root
        elif root != self.root:
            raise CheckpointLayoutError(self.r.label, "snapshot", f"every file from one commit ({self.root.name})",
                                        f"{path} from {root.name}", "the branch moved during the download; pin a "
                                        "commit with revision=... or retry")
        self.got.append(path)
        return local

    def component(self, sub: str) -> None:
        """``sub/config.json`` + the safetensors weights (single file or index + shards)."""
        self.get(f"{sub}/config.json")
        if self.get(f"{sub}/{WEIGHTS_NAME}", required=False) is not None:
            return
        index = self.get(f"{sub}/{INDEX_NAME}", required=False)
        if index is None:
            self.missing.append(f"{sub}/{WEIGHTS_NAME} (or {INDEX_NAME})")
            return
        try:
            shards = sorted(set(json.loads(index.read_text())["weight_map"].values()))
        except (ValueError, KeyError, TypeError):
            raise CheckpointLayoutError(index, "weight_map", "a JSON object {tensor: shard}", "an unreadable index") \
                from None
        for shard in shards:
            if not shard.endswith(".safetensors"):
                raise CheckpointLayoutError(index, "weight_map", "safetensors shards", shard)
            self.get(f"{sub}/{shard}")

    def found(self) -> str:
        """What the repository (online) or the local cache (offline) holds, for error messages."""
        if not self.offline:
            try:
                from huggingface_hub import HfApi

                files = HfApi(endpoint=self.endpoint, token=self.token).list_repo_files(
                    self.spec.repo_id, revision=self.r.revision)
                pickles = [f for f in files if f.endswith(_PICKLES)]
                note = (f" — pickle-based files ({', '.join(pickles)}) are never loaded by oscar; convert them to "
                        "safetensors") if pickles else ""
                return (", ".join(sorted(files)) or "an empty repository") + note
            except Exception as exc:  # noqa: BLE001 - listing is a courtesy for the message
                return f"(could not list the repository: {type(exc).__name__})"
        if self.root is not None and self.root.is_dir():
            files = sorted(p.relative_to(self.root).as_posix() for p in self.root.rglob("*") if p.is_file())
            return "in the local cache: " + (", ".join(files) or "nothing")
        return "nothing in the local cache (offline: HF_HUB_OFFLINE=1 or local_files_only=True)"

    def raise_missing(self, expected) -> None:
        if not self.missing:
            return
        hint = f"missing {', '.join(self.missing)}"
        if self.offline:
            hint += "; offline mode reads only the local cache: run `oscar zoo pull NAME` online once"
        if self.spec.source == "table" and self.spec.name == "oscar-2b":
            hint += "; the layout of this release is unverified: please report what the repository holds"
        raise CheckpointLayoutError(self.r.label, "files", ", ".join(expected), self.found(), hint)


def fetch(resolved: Resolved, *, cache_dir=None, endpoint=None, local_files_only: bool | None = None,
          force_download: bool = False, token=None, verify: bool = True) -> tuple[Path, str]:
    """Download (or find in the cache) what ``resolved`` needs; verify it; return (folder, kind)."""
    if resolved.folder is not None:
        kind = local_kind(resolved.folder)
        if verify:
            verify_folder(resolved.folder, {}, label=str(resolved.folder))
        return resolved.folder, kind
    spec = resolved.spec
    f = _Fetcher(resolved, cache_dir, endpoint, is_offline(local_files_only), force_download, token)
    if spec.kind == "oscar":
        if f.get(MODEL_FILE) is None:
            f.raise_missing(OSCAR_LAYOUT)
        manifest = f.get(MANIFEST_NAME, required=False)
        listed = sorted(json.loads(manifest.read_text()).get("files", {})) if manifest is not None else []
        if listed:
            for path in listed:
                f.get(path)
        else:
            f.component("transformer")
            f.component("vae")
            f.get(EMPTY_PROMPT_FILE, required=False)
        expected = OSCAR_LAYOUT
    else:
        f.component("transformer")
        f.component("vae")
        expected = ("transformer/config.json", f"transformer/{WEIGHTS_NAME} (or an index + shards)",
                    "vae/config.json", f"vae/{WEIGHTS_NAME}")
    for file in spec.files:
        f.get(file.path)
    f.raise_missing(expected)
    if verify:
        verify_folder(f.root, {file.path: file.sha256 for file in spec.files}, label=resolved.label, files=f.got,
                      name=spec.name)
    return f.root, spec.kind


def verify_folder(root: Path, pinned: dict[str, str | None], *, label: str, files=None, name: str | None = None) -> None:
    """Pinned sha256 (table/registry), then the folder's manifest, then every safetensors file's structure."""
    hint_name = name or label
    try:
        verify_files(root, pinned, source=label)
        manifest = read_manifest(root)
        if manifest is not None:
            verify_files(root, {p: m.get("sha256") for p, m in manifest.items()}, source=label)
        paths = files if files is not None else [p.relative_to(root).as_posix() for p in root.rglob("*.safetensors")]
        for rel in paths:
            if rel.endswith(".safetensors"):
                check_safetensors(root / rel)
    except CheckpointIntegrityError as exc:
        raise CheckpointIntegrityError(exc.path, exc.what, exc.expected, exc.found,
                                       f"the file is corrupted, partial or was changed; fetch it again with "
                                       f"`oscar zoo pull --force {hint_name}` (checkpoint {label})") from None
