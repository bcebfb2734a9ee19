"""The sha256 of a checkpoint file, remembered between processes while the file is unchanged.

Loading a checkpoint checks every weight file against its pinned, locked or manifest sha256. Hashing reads the
whole file at about 1.5 GB/s on this CPU (2 shared cores): ≈3 s of every ``oscar rollout`` of the 2B model
(≈4.5 GB), before a weight is read. :func:`file_sha256` keeps each digest it computes in
``$OSCAR_CACHE/verified/<sha256 of the file's real path>.json`` together with the file's identity — size,
``st_mtime_ns``, ``st_ctime_ns``, inode and device — and a later call whose ``os.stat`` matches all five returns
the remembered digest without reading the file.

Any write to the file (a new download, ``cp`` over it, a truncation, an edit even with the modification time set
back) changes its ``st_ctime_ns``, which no user program can set, so a changed file is hashed again and checked as
before. What this does not catch is a change without a write through the filesystem (bits rotting on the disk): set
``OSCAR_VERIFY=full`` to hash every file on every load. A digest is remembered only when the file's identity was
the same before and after hashing it; an unreadable or unwritable record is ignored (the file is hashed).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from .._util.log import get_logger

__all__ = ["file_sha256", "sha256_file", "verified_dir"]

_log = get_logger(__name__)
_CHUNK = 8 * 1024 * 1024


def sha256_file(path) -> str:
    """Hex sha256 of a file's bytes (read in 8 MiB chunks; follows symlinks, e.g. the Hub cache's)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(_CHUNK), b""):
            h.update(block)
    return h.hexdigest()


_FIELDS = ("st_size", "st_mtime_ns", "st_ctime_ns", "st_ino", "st_dev")


def verified_dir() -> Path:
    """``$OSCAR_CACHE/verified``, else ``$XDG_CACHE_HOME/oscar/verified`` (``~/.cache/oscar/verified``)."""
    root = os.environ.get("OSCAR_CACHE")
    if root:
        return Path(root) / "verified"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "oscar" / "verified"


def _identity(path: Path) -> list[int]:
    st = os.stat(path)
    return [int(getattr(st, f)) for f in _FIELDS]


def file_sha256(path) -> str:
    """Hex sha256 of ``path``'s bytes: remembered if the file is unchanged since it was last hashed, else computed
    (and remembered). ``OSCAR_VERIFY=full`` always computes it."""
    real = Path(os.path.realpath(path))
    record = verified_dir() / f"{hashlib.sha256(str(real).encode('utf-8')).hexdigest()}.json"
    full = os.environ.get("OSCAR_VERIFY", "").strip().lower() == "full"
    before = _identity(real)
    if not full:
        try:
            saved = json.loads(record.read_text())
            if saved.get("path") == str(real) and saved.get("identity") == before:
                return str(saved["sha256"])
        except (OSError, ValueError, KeyError, AttributeError):
            pass  # no record, or one that cannot be used: hash the file
    digest = sha256_file(real)
    if _identity(real) == before:  # unchanged while it was read: the digest belongs to this identity
        try:
            from .._util.atomic import atomic_write_bytes

            record.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(record, json.dumps({"path": str(real), "identity": before, "sha256": digest}).encode())
        except OSError as exc:
            _log.debug("could not remember the sha256 of %s in %s: %s", real, record, exc)
    return digest
