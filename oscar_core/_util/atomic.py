"""Write files so that a crash never leaves a half-written output, and sweep what killed writers left.

Every temporary an oscar writer makes beside its target is named
``.<name>.<pid>.<random>.tmp[<suffix>]`` (:func:`tmp_prefix`): the writer's
process id is in the name. A writer killed at any moment (kill -9, power
loss) leaves at most such a temporary, never a partial file at the final
name; the next oscar command writing into that folder removes the
temporaries whose process is no longer running (:func:`sweep_dead_temporaries`,
done once per folder and process by :func:`atomic_output` and the other
writers). Process ids are those of this machine: a folder shared by several
machines (NFS) must not be written by two of them at once.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
from pathlib import Path

from ..errors import OutputPathError

__all__ = ["atomic_output", "atomic_write_bytes", "tmp_prefix", "pid_alive", "sweep_dead_temporaries", "sweep_once"]

# .<name>.<pid>.<random>.tmp<anything>: name may itself hold dots; the pid is the last all-digit part before it
TMP_NAME = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)\.(?P<rand>[A-Za-z0-9_-]+)\.tmp(?P<suffix>.*)$")
_SWEPT: set[tuple[int, str]] = set()


def tmp_prefix(path: str | Path) -> str:
    """The prefix of a temporary for ``path``: ``.<name>.<pid>.`` (add a random part and ``.tmp``)."""
    return f".{Path(path).name}.{os.getpid()}."


def pid_alive(pid: int) -> bool:
    """True while a process ``pid`` exists on this machine (one we may not signal counts as alive)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def sweep_dead_temporaries(folder: str | Path, *, target: str | None = None) -> list[Path]:
    """Remove the temporaries (files or folders) in ``folder`` whose writer process is no longer running.

    Only names of the form ``.<name>.<pid>.<random>.tmp[<suffix>]`` are
    touched, and only when ``pid`` is not a running process (never this
    one); ``target`` limits the sweep to temporaries of that file name.
    Returns what was removed; a missing folder is nothing to sweep.
    """
    folder = Path(folder)
    removed: list[Path] = []
    try:
        entries = list(folder.iterdir())
    except (FileNotFoundError, NotADirectoryError):
        return removed
    for p in entries:
        m = TMP_NAME.match(p.name)
        if m is None or (target is not None and m["name"] != target):
            continue
        pid = int(m["pid"])
        if pid == os.getpid() or pid_alive(pid):
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
        removed.append(p)
    return removed


def sweep_once(folder: str | Path) -> list[Path]:
    """:func:`sweep_dead_temporaries` the first time this process writes into ``folder``; [] after that."""
    key = (os.getpid(), os.path.abspath(folder))
    if key in _SWEPT:
        return []
    removed = sweep_dead_temporaries(folder)
    if Path(folder).is_dir():
        _SWEPT.add(key)
    return removed


@contextlib.contextmanager
def atomic_output(path: str | Path):
    """Yield a temporary path beside ``path`` (same suffix); rename onto ``path`` on success.

    Raises :class:`OutputPathError` before any work if the folder is missing
    or not writable. On an exception the temporary file is removed; the
    temporary is named after this process (:func:`tmp_prefix`), and dead
    processes' temporaries in the folder are swept first.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise OutputPathError(path, f"folder {path.parent} does not exist")
    if path.is_dir():
        raise OutputPathError(path, "it is a folder")
    sweep_once(path.parent)
    try:
        fd, tmp = tempfile.mkstemp(prefix=tmp_prefix(path), suffix=f".tmp{path.suffix}", dir=path.parent)
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
