"""A local registry of user models: ``name → repo_id@revision`` + file hashes.

So that a fine-tuned model, once pushed, loads back by name
(``oscar_zoo.load("my-franka-ft")``) with its hashes checked. It is a JSON
file at ``$OSCAR_ZOO_REGISTRY``, else ``$XDG_CONFIG_HOME/oscar/zoo.json``
(``~/.config/oscar/zoo.json``)::

    {"format": "oscar-zoo-registry", "version": 1,
     "models": {"my-franka-ft": {"repo_id": "me/oscar-franka-ft", "revision": "<commit>",
                                 "kind": "oscar", "files": {"transformer/config.json": "<sha256>", ...},
                                 "chunk_frames": 81, ...}}}

User names may not shadow a name of the built-in table, and contain no "/"
(that would read as a Hub repo id).
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

from oscar_core._util.atomic import atomic_write_bytes
from oscar_core.model.errors import CheckpointLayoutError

from ._table import CHECKPOINTS, KINDS, CheckpointSpec, FileSpec

__all__ = ["registry_path", "user_models", "register", "unregister"]

FORMAT = "oscar-zoo-registry"
_NAME = re.compile(r"^[a-z0-9][a-z0-9._-]*$")
_CARD_KEYS = ("license", "paper", "embodiments", "chunk_frames", "width", "height", "fps", "text_encoder_id", "notes")


def registry_path() -> Path:
    """Where the user registry lives (see the module docstring)."""
    explicit = os.environ.get("OSCAR_ZOO_REGISTRY")
    if explicit:
        return Path(explicit)
    return Path(os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config") / "oscar" / "zoo.json"


def _read(path: Path) -> dict:
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
        models = data["models"]
        if data.get("format") != FORMAT or not isinstance(models, dict):
            raise ValueError
    except (ValueError, KeyError, TypeError):
        raise CheckpointLayoutError(
            path, "models", f"a {FORMAT} JSON file", "an unreadable registry", "fix or delete the file"
        ) from None
    return models


def _spec(name: str, entry: dict, path: Path) -> CheckpointSpec:
    try:
        return CheckpointSpec(
            name=name,
            repo_id=entry["repo_id"],
            revision=entry.get("revision"),
            kind=entry.get("kind", "oscar"),
            license=entry.get("license"),
            paper=entry.get("paper"),
            embodiments=tuple(entry.get("embodiments", ())),
            chunk_frames=entry.get("chunk_frames"),
            width=entry.get("width"),
            height=entry.get("height"),
            fps=entry.get("fps"),
            files=tuple(FileSpec(p, h) for p, h in sorted(entry.get("files", {}).items())),
            text_encoder_id=entry.get("text_encoder_id"),
            notes=entry.get("notes", ""),
            source=str(path),
        )
    except (KeyError, TypeError):
        raise CheckpointLayoutError(
            path, f"models.{name}", "an entry with at least 'repo_id'", repr(entry)[:120]
        ) from None


def user_models() -> tuple[CheckpointSpec, ...]:
    """The user registry's entries, sorted by name."""
    path = registry_path()
    return tuple(_spec(name, entry, path) for name, entry in sorted(_read(path).items()))


def register(
    name: str,
    repo_id: str,
    revision: str | None = None,
    *,
    kind: str = "oscar",
    files: dict[str, str | None] | None = None,
    overwrite: bool = False,
    **card,
) -> CheckpointSpec:
    """Add ``name → repo_id@revision`` to the user registry; returns its spec.

    files: {path in the repo: sha256 or None}, checked on every load (export
        and push fill it from the folder's manifest).
    card: optional fields among license, paper, embodiments, chunk_frames,
        width, height, fps, text_encoder_id, notes.
    """
    if not _NAME.match(name or ""):
        raise ValueError(f"zoo name: expected lowercase letters, digits, '.', '_' or '-' (no '/'), found {name!r}")
    if any(spec.name == name for spec in CHECKPOINTS):
        raise ValueError(
            f"zoo name {name!r}: expected a name not in the built-in table "
            f"({', '.join(s.name for s in CHECKPOINTS)}), found a clash"
        )
    if kind not in KINDS:
        raise ValueError(f"zoo kind: expected one of {KINDS}, found {kind!r}")
    unknown = sorted(set(card) - set(_CARD_KEYS))
    if unknown:
        raise ValueError(f"register: expected card fields among {_CARD_KEYS}, found {unknown}")
    path = registry_path()
    models = _read(path)
    if name in models and not overwrite:
        raise ValueError(
            f"{path}: model {name!r} is already registered (-> {models[name]['repo_id']}); "
            "pass overwrite=True to replace it"
        )
    entry = {"repo_id": repo_id, "revision": revision, "kind": kind, "files": dict(sorted((files or {}).items()))}
    entry.update({k: (list(v) if k == "embodiments" else v) for k, v in card.items() if v is not None})
    models[name] = entry
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"format": FORMAT, "version": 1, "models": dict(sorted(models.items()))}
    atomic_write_bytes(path, (json.dumps(payload, indent=2) + "\n").encode())
    return _spec(name, entry, path)


def unregister(name: str) -> bool:
    """Remove ``name`` from the user registry; returns whether it was there."""
    path = registry_path()
    models = _read(path)
    if name not in models:
        return False
    del models[name]
    atomic_write_bytes(path, (json.dumps({"format": FORMAT, "version": 1, "models": models}, indent=2) + "\n").encode())
    return True
