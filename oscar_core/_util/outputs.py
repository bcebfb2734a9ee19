"""Check that a command's outputs can be written, before it does any work.

Every CLI option that names something a command writes is marked with
:func:`output_option` (its kind: a file, a folder, or either). The ``oscar``
command checks every marked option's value with :func:`check_writable` after
parsing and before the sub-command runs, so a folder the user may not write
is one line and exit 2, never a traceback halfway through a job. Commands
whose output path comes from elsewhere (``oscar train``'s ``run_dir`` in a
config) call :func:`check_writable` themselves.

The check does not trust permission bits (``os.access`` says yes to root on
a read-only file system): it finds the nearest folder that exists on the
way to the path and creates, then removes, a temporary file in it.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ..errors import OutputPathError

__all__ = ["OUTPUT_KINDS", "output_option", "output_kind", "check_writable"]

OUTPUT_KINDS = ("file", "folder", "any")  # any: a file or a folder (the command's own check tells them apart)
_ATTR = "oscar_output"


def output_option(action, kind: str = "file"):
    """Mark an ``argparse`` action (what ``add_argument`` returns) as an output of ``kind``; returns it."""
    if kind not in OUTPUT_KINDS:
        raise ValueError(f"kind: expected one of {OUTPUT_KINDS}, found {kind!r}")
    setattr(action, _ATTR, kind)
    return action


def output_kind(action) -> str | None:
    """The kind :func:`output_option` gave ``action``, else None."""
    return getattr(action, _ATTR, None)


def _probe(folder: Path) -> str | None:
    """None when a file can be created in ``folder`` (tried for real), else why not."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".oscar-write-check.{os.getpid()}.", suffix=".tmp", dir=folder)
    except OSError as exc:
        return exc.strerror or type(exc).__name__
    os.close(fd)
    try:
        os.unlink(tmp)
    except OSError:
        pass
    return None


def check_writable(path, kind: str = "file") -> Path | None:
    """Raise :class:`OutputPathError` unless ``path`` can be written as a ``kind`` ("file", "folder", "any": either).

    A missing path is fine when the nearest existing folder above it is a
    folder this process can create files in (missing folders between are
    made by the writer). An existing path must be of the right kind (a file
    output is not a folder; a folder output is not a file). fsspec URLs
    (``s3://…``) are not checked here. Returns the path (None for a URL).
    """
    raw = str(path)
    if "://" in raw:
        return None
    p = Path(raw)
    if p.exists():
        if kind == "folder" and not p.is_dir():
            raise OutputPathError(p, "it is a file, expected a folder")
        if kind == "file" and p.is_dir():
            raise OutputPathError(p, "it is a folder, expected a file")
        folder = p if p.is_dir() else p.parent
    else:
        folder = p.parent
        while not folder.exists() and folder != folder.parent:
            folder = folder.parent
        if not folder.is_dir():
            raise OutputPathError(p, f"{folder} is a file, not a folder")
    why = _probe(folder)
    if why is not None:
        raise OutputPathError(p, f"folder {folder} is not writable ({why})")
    return p
