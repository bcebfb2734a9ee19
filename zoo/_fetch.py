"""Resolve a name / Hub id / folder, download what the layout needs, and verify it.

Online, one request (:func:`._hub.probe`) resolves the revision to a commit
and lists the repository; the layout (``oscar_core.model.layouts``: oscar,
diffusers or cosmos-native) is decided from that listing, and only the files
it needs are fetched with ``hf_hub_download`` at that commit, into the
standard Hub cache. Offline, the commit comes from the pull's lock file or
the cache's refs, and the snapshot folder is read with no network at all.
Only JSON, safetensors and (cosmos-native) one ``.pt`` state dict — read
with ``weights_only=True`` — are ever requested.

``HF_ENDPOINT`` and ``HF_HUB_OFFLINE`` are read when a function is called
(huggingface_hub itself reads them once, at import), and passed on
explicitly; ``endpoint=`` / ``local_files_only=`` arguments override them.
"""

from __future__ import annotations

import json  # noqa: F401
import os
import re
from dataclasses import dataclass
from pathlib import Path

from oscar_core.errors import OscarError
from oscar_core.model._files import EMPTY_PROMPT_FILE, MODEL_FILE
from oscar_core.model._verified import file_sha256
from oscar_core.model.errors import CheckpointIntegrityError, CheckpointLayoutError
from oscar_core.model.layouts import SCHEDULER_CONFIG, Layout, detect_layout, list_folder
from oscar_core.model.manifest import MANIFEST_NAME, read_manifest
from oscar_core.model.weights import CONFIG_NAME, INDEX_NAME, WEIGHTS_NAME, check_safetensors

from ._hub import HubUnreachableError, Lock, cached_commit, probe, read_lock, snapshot_folder, write_lock
from ._registry import user_models
from ._table import CHECKPOINTS, CheckpointSpec

__all__ = [
    "UnknownModelError",
    "Resolved",
    "resolve",
    "fetch",
    "list_models",
    "is_offline",
    "OSCAR_LAYOUT",
    "needed_files",
    "hub_snapshot",
    "HubUnreachableError",
    "Fetched",
]

OSCAR_LAYOUT = (
    MODEL_FILE,
    "transformer/config.json",
    f"transformer/{WEIGHTS_NAME} (or an index + shards)",
    "vae/config.json",
    f"vae/{WEIGHTS_NAME}",
    f"{MANIFEST_NAME} (optional)",
    f"{EMPTY_PROMPT_FILE} (optional)",
)
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
            if revision is not None and spec.bundled:
                raise UnknownModelError(
                    f"model {text!r}: expected no revision (it is bundled with oscar-wm), found {revision!r}"
                )
            if revision is not None:
                spec = _replace_revision(spec, revision)
            return Resolved(f"{spec.name} ({spec.repo_id}@{spec.revision or 'main'})", spec=spec)
    if text.count("/") == 1 and all(text.split("/")) and not text.startswith((".", "/", "~")):
        for spec in list_models():  # a known repo id gets its table entry (hashes, kind, card)
            if spec.repo_id == text:
                if revision is not None:
                    spec = _replace_revision(spec, revision)
                return Resolved(f"{spec.name} ({text}@{spec.revision or 'main'})", spec=spec)
        spec = CheckpointSpec(
            name=text, repo_id=text, revision=revision, kind="oscar", license=None, paper=None, source="hub id"
        )
        return Resolved(f"{text}@{revision or 'main'}", spec=spec)
    known = ", ".join(s.name for s in list_models())
    raise UnknownModelError(
        f"model {text!r}: expected a zoo name ({known}), a Hub repo id 'owner/name' or an "
        f"existing folder, found none of these"
    )


def bundled_folder(spec: CheckpointSpec) -> Path:
    """The folder of a checkpoint shipped inside the ``oscar_zoo`` package (``spec.bundled``)."""
    folder = Path(__file__).resolve().parent / spec.bundled
    if not folder.is_dir():
        raise CheckpointLayoutError(
            spec.name, "bundled", f"the folder {folder} shipped with oscar-wm", "no such folder", "reinstall oscar-wm"
        )
    return folder


def _replace_revision(spec: CheckpointSpec, revision: str) -> CheckpointSpec:
    from dataclasses import replace

    # hashes pinned for another revision do not apply to this one
    files = spec.files if revision == spec.revision else tuple(type(f)(f.path, None) for f in spec.files)
    return replace(spec, revision=revision, files=files)


_SHARD = re.compile(r"^diffusion_pytorch_model-\d+-of-\d+\.safetensors$")


def _component(files: set[str], sub: str) -> list[str]:
    """config + non-variant weights (single file, or index + numbered shards) of ``sub/``."""
    out = [f"{sub}/{CONFIG_NAME}"] if f"{sub}/{CONFIG_NAME}" in files else []
    if f"{sub}/{WEIGHTS_NAME}" in files:
        return out + [f"{sub}/{WEIGHTS_NAME}"]
    if f"{sub}/{INDEX_NAME}" in files:
        shards = [f for f in files if f.startswith(sub + "/") and _SHARD.match(f[len(sub) + 1 :])]
        return out + [f"{sub}/{INDEX_NAME}"] + sorted(shards)
    return out


def needed_files(layout: Layout, files) -> list[str]:
    """The files of a listing that loading ``layout`` reads (nothing else is downloaded)."""
    files = set(files)
    need = (
        _component(files, "transformer") + _component(files, "vae")
        if layout.kind != "cosmos-native"
        else [layout.native_file] + _component(files, "vae")
    )
    if layout.kind == "cosmos-native":
        beside = str(Path(layout.native_file).parent / CONFIG_NAME).removeprefix("./")
        need += [beside] if beside in files else []
    for optional in (MODEL_FILE, MANIFEST_NAME, EMPTY_PROMPT_FILE, SCHEDULER_CONFIG):
        if optional in files and (layout.kind == "oscar" or optional == SCHEDULER_CONFIG):
            need.append(optional)
    return sorted(set(need))


@dataclass
class Fetched:
    """A checkpoint on disk: its folder, layout, label, commit (Hub) and the files that were verified."""

    folder: Path
    layout: Layout
    label: str
    commit: str | None = None
    files: tuple[str, ...] = ()


def _download(repo_id: str, commit: str, paths, *, cache_dir, endpoint, token, force: bool) -> Path:
    """hf_hub_download each path at ``commit``; returns the snapshot folder."""
    from huggingface_hub import hf_hub_download

    from ._hub import hub_timeout

    root = None
    for path in paths:
        try:
            local = hf_hub_download(
                repo_id,
                path,
                revision=commit,
                cache_dir=cache_dir,
                endpoint=endpoint,
                force_download=force,
                token=token,
                etag_timeout=hub_timeout(),
            )
        except OSError as exc:  # connection errors are OSErrors too: say which
            name = type(exc).__name__
            if "Connect" in name or "Timeout" in name or "Offline" in name:
                raise HubUnreachableError(
                    f"cannot reach the Hub ({endpoint or 'huggingface.co'}: {name} while "
                    f"downloading {path}); set HF_HUB_OFFLINE=1 to use the cache"
                ) from None
            raise CheckpointIntegrityError(
                f"{repo_id}@{commit}: {path}", "download", "a complete file", f"{name}: {exc}"
            ) from None
        root = Path(str(local)[: -len(path)])
    return root


def fetch(
    resolved: Resolved,
    *,
    cache_dir=None,
    endpoint=None,
    local_files_only: bool | None = None,
    force_download: bool = False,
    token=None,
    verify: bool = True,
    native_file: str | None = None,
    update_lock: bool = False,
) -> Fetched:
    """Download (or find in the cache) what ``resolved`` needs, verify it, and say which layout it is.

    update_lock: resolve the revision anew and rewrite the lock (``pull``);
    otherwise an existing lock pins the commit and its hashes are checked.
    """
    if resolved.folder is not None:
        folder = resolved.folder
        files = list_folder(folder)
        layout = detect_layout(files, folder, native_file)
        need = needed_files(layout, files)
        if verify:
            verify_folder(folder, {}, label=str(folder), files=need)
        return Fetched(folder, layout, str(folder), None, tuple(need))
    spec = resolved.spec
    if spec.bundled:  # shipped inside the package: no Hub, no cache, every file's sha256 pinned
        folder = bundled_folder(spec)
        files = list_folder(folder)
        layout = detect_layout(files, resolved.label, native_file)
        need = needed_files(layout, files)
        if verify or update_lock:
            verify_folder(
                folder, {f.path: f.sha256 for f in spec.files}, label=resolved.label, files=need, name=spec.name
            )
        return Fetched(folder, layout, resolved.label, None, tuple(need))
    endpoint = endpoint or os.environ.get("HF_ENDPOINT") or None
    cache_dir = str(cache_dir) if cache_dir is not None else (os.environ.get("HF_HUB_CACHE") or None)
    revision = resolved.revision
    lock = None if update_lock else read_lock(spec.repo_id, revision, cache_dir)
    if is_offline(local_files_only):
        commit = lock.commit if lock else cached_commit(spec.repo_id, revision, cache_dir)
        root = snapshot_folder(spec.repo_id, commit, cache_dir) if commit else None
        if root is None or not root.is_dir():
            raise CheckpointLayoutError(
                resolved.label,
                "local cache",
                f"a cached snapshot of {spec.repo_id}@{revision}",
                "nothing in the local cache (offline: HF_HUB_OFFLINE=1 or local_files_only=True)",
                "run `oscar zoo pull NAME` online once",
            )
        files = list_folder(root)
    else:
        info = probe(spec.repo_id, lock.commit if lock else revision, endpoint=endpoint, token=token)
        commit, files, root = info.commit, list(info.files), None
    try:
        layout = detect_layout(files, resolved.label, native_file)
    except CheckpointLayoutError as exc:
        if spec.source == "table" and spec.name == "oscar-2b":
            hint = "; ".join(
                h
                for h in (exc.hint, "the layout of this release is unverified: please report what the repository holds")
                if h
            )
            raise CheckpointLayoutError(exc.source, exc.what, exc.expected, exc.found, hint) from None
        raise
    need = needed_files(layout, files)
    if root is None:
        root = _download(
            spec.repo_id, commit, need, cache_dir=cache_dir, endpoint=endpoint, token=token, force=force_download
        )
    else:
        absent = [p for p in need if not (root / p).is_file()]
        if absent:
            raise CheckpointLayoutError(
                resolved.label,
                "local cache",
                ", ".join(need),
                f"missing {', '.join(absent)}",
                "offline mode reads only the local cache: run `oscar zoo pull NAME` online",
            )
    hashes = None
    if verify or update_lock:
        pinned = {f.path: f.sha256 for f in spec.files}
        hashes = verify_folder(
            root,
            pinned,
            label=resolved.label,
            files=need,
            name=spec.name,
            locked=lock.files if lock else None,
            hash_all=update_lock,
        )
    if update_lock:
        write_lock(Lock(spec.repo_id, revision, commit, layout.kind, hashes), cache_dir)
    return Fetched(root, layout, resolved.label, commit, tuple(need))


def hub_snapshot(
    repo_id: str,
    revision: str | None,
    patterns,
    *,
    cache_dir=None,
    endpoint=None,
    local_files_only: bool | None = None,
    token=None,
) -> tuple[Path, str]:
    """Files of ``repo_id`` matching ``patterns`` (fnmatch) at ``revision``: (snapshot folder, commit)."""
    from fnmatch import fnmatch

    revision = revision or "main"
    endpoint = endpoint or os.environ.get("HF_ENDPOINT") or None
    cache_dir = str(cache_dir) if cache_dir is not None else (os.environ.get("HF_HUB_CACHE") or None)
    if is_offline(local_files_only):
        commit = cached_commit(repo_id, revision, cache_dir)
        root = snapshot_folder(repo_id, commit, cache_dir) if commit else None
        if root is None or not root.is_dir():
            raise CheckpointLayoutError(
                f"{repo_id}@{revision}",
                "local cache",
                f"a cached snapshot of {repo_id}",
                "nothing in the local cache (offline)",
                "run it online once",
            )
        return root, commit
    info = probe(repo_id, revision, endpoint=endpoint, token=token)
    need = [f for f in info.files if any(fnmatch(f, p) for p in patterns)]
    if not need:
        raise CheckpointLayoutError(f"{repo_id}@{revision}", "files", ", ".join(patterns), ", ".join(info.files))
    root = _download(repo_id, info.commit, need, cache_dir=cache_dir, endpoint=endpoint, token=token, force=False)
    return root, info.commit


def verify_folder(
    root: Path,
    pinned: dict[str, str | None],
    *,
    label: str,
    files=None,
    name: str | None = None,
    locked: dict[str, str] | None = None,
    hash_all: bool = False,
) -> dict[str, str]:
    """Hash each file once and check it against the pinned (table/registry), locked and manifest sha256.

    Also checks every safetensors file's structure. Only files with an
    expected hash are hashed, unless ``hash_all`` (a pull writing its lock).
    Returns {file: sha256} of the hashed files among ``files`` (default:
    every file under ``root``).
    """
    hint_name = name or label
    files = list(files) if files is not None else list_folder(root)
    try:
        expected: dict[str, list[tuple[str, str]]] = {}
        for origin, table in (("pinned", pinned), ("lock file", locked or {})):
            for path, digest in table.items():
                if digest:
                    expected.setdefault(path, []).append((digest.lower(), origin))
        manifest = read_manifest(root) if (root / MANIFEST_NAME).is_file() else None
        for path, meta in (manifest or {}).items():
            if meta.get("sha256"):
                expected.setdefault(path, []).append((meta["sha256"].lower(), "manifest"))
        missing = sorted(p for p in set(expected) | set(pinned) if not (root / p).is_file())
        if missing:
            raise CheckpointLayoutError(
                label, "files", ", ".join(sorted(set(expected) | set(pinned))), f"missing {', '.join(missing)}"
            )
        hashes = {}
        for rel in sorted(set(files) | set(expected)):
            if rel not in expected and not hash_all:
                if rel.endswith(".safetensors"):
                    check_safetensors(root / rel)
                continue
            hashes[rel] = file_sha256(root / rel)  # remembered while unchanged (oscar_core.model._verified)
            for digest, origin in expected.get(rel, []):
                if hashes[rel] != digest:
                    raise CheckpointIntegrityError(root / rel, "sha256", f"{digest} ({origin})", hashes[rel])
            if rel.endswith(".safetensors"):
                check_safetensors(root / rel)
        return {k: v for k, v in hashes.items() if k in set(files)}
    except CheckpointIntegrityError as exc:
        raise CheckpointIntegrityError(
            exc.path,
            exc.what,
            exc.expected,
            exc.found,
            f"the file is corrupted, partial or was changed; fetch it again with "
            f"`oscar zoo pull --force {hint_name}` (checkpoint {label})",
        ) from None
