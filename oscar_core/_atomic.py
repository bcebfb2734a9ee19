"""Write files so that a crash never leaves a half-written output."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from .errors import OutputPathError

__all__ = ["atomic_output", "atomic_write_bytes"]


@contextlib.contextmanager
def atomic_output(path: str | Path):
    """Yield a temporary path beside ``path`` (same suffix); rename onto ``path`` on success.

    Raises :class:`OutputPathError` before any work if the folder is missing
    or not writable. On an exception the temporary file is removed.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise OutputPathError(path, f"folder {path.parent} does not exist")
    if path.is_dir():
        raise OutputPathError(path, "it is a folder")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    except OSError as exc:
        raise OutputPathError(path, exc.strerror or str(exc)) from None
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; outputs get the usual mode
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    with atomic_output(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)
