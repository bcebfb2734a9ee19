"""sha256 manifests of checkpoint folders: written on export, checked on load.

``oscar_manifest.json`` lists every other file of a folder with its size and
sha256. It detects corrupted and partial files (integrity), not malicious
ones: whoever can replace a file can replace the manifest too — pinned
hashes in the zoo table or a user's registry are what vouch for a source.
"""

from __future__ import annotations

import json
from pathlib import Path

from ._verified import file_sha256, sha256_file
from .errors import CheckpointIntegrityError, CheckpointLayoutError

__all__ = ["MANIFEST_NAME", "sha256_file", "write_manifest", "read_manifest", "verify_files"]

MANIFEST_NAME = "oscar_manifest.json"


def _files(folder: Path) -> list[str]:
    return sorted(
        p.relative_to(folder).as_posix()
        for p in folder.rglob("*")
        if p.is_file()
        and p.name != MANIFEST_NAME
        and not any(part.startswith(".") for part in p.relative_to(folder).parts)
    )


def write_manifest(folder) -> dict[str, dict]:
    """Hash every file under ``folder`` (hidden ones excepted) into ``folder/oscar_manifest.json``."""
    folder = Path(folder)
    files = {
        rel: {"size": (folder / rel).stat().st_size, "sha256": sha256_file(folder / rel)} for rel in _files(folder)
    }
    (folder / MANIFEST_NAME).write_text(
        json.dumps({"format": "oscar-manifest", "version": 1, "files": files}, indent=2, sort_keys=True) + "\n"
    )
    return files


def read_manifest(folder) -> dict[str, dict] | None:
    """The ``files`` mapping of ``folder``'s manifest, or None when there is none."""
    path = Path(folder) / MANIFEST_NAME
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
        files = data["files"]
        if not isinstance(files, dict):
            raise TypeError
    except (ValueError, KeyError, TypeError):
        raise CheckpointLayoutError(
            path, "files", "a JSON object {path: {size, sha256}}", "an unreadable manifest"
        ) from None
    return files


def verify_files(folder, expected: dict[str, str | None], source: str | None = None) -> None:
    """Check that each ``folder/path`` exists and, where a sha256 is given, matches it.

    expected: {relative path: hex sha256 or None (existence only)}.
    Raises CheckpointLayoutError for missing files, CheckpointIntegrityError
    for a hash mismatch (naming the file, the expected and the found hash).
    """
    folder = Path(folder)
    missing = sorted(p for p in expected if not (folder / p).is_file())
    if missing:
        raise CheckpointLayoutError(
            source or folder, "files", ", ".join(sorted(expected)), f"missing {', '.join(missing)}"
        )
    for rel, digest in sorted(expected.items()):
        if digest is None:
            continue
        found = file_sha256(folder / rel)  # remembered while the file is unchanged (OSCAR_VERIFY=full: always read)
        if found != digest.lower():
            raise CheckpointIntegrityError(
                folder / rel,
                "sha256",
                digest.lower(),
                found,
                "the file is corrupted, partial or was changed; download it again (oscar zoo pull --force NAME)",
            )
