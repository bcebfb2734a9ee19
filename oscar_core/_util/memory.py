"""Refuse an array that cannot fit in memory with a message, before numpy raises a traceback.

``--size 100000x100000`` asks for 447 GiB of (T, H, W, 3) uint8 frames;
numpy's ``_ArrayMemoryError`` would say so only as a traceback, after the
work before it. :func:`check_fits` compares a planned array's bytes with the
memory this process can still get (``MemAvailable`` from ``/proc/meminfo``,
capped by a cgroup v2 limit; unknown elsewhere, where nothing is refused).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import OscarError

__all__ = ["ArraySizeError", "available_bytes", "check_fits"]

GIB = 1024**3


class ArraySizeError(OscarError, ValueError):
    """An array oscar was asked to make needs more memory than is available."""


def available_bytes() -> int | None:
    """Bytes of memory this process can still allocate, or None when the system does not say."""
    avail = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = int(line.split()[1]) * 1024
                break
    except (OSError, ValueError, IndexError):
        return None
    try:  # a container's own limit (cgroup v2) is tighter than the host's free memory
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        used = Path("/sys/fs/cgroup/memory.current").read_text().strip()
        if limit != "max" and avail is not None:
            avail = min(avail, max(0, int(limit) - int(used)))
    except (OSError, ValueError):
        pass
    return avail


def check_fits(shape: tuple[int, ...], itemsize: int, what: str, hint: str, available: int | None = None) -> None:
    """Raise :class:`ArraySizeError` when an array of ``shape`` × ``itemsize`` bytes exceeds available memory.

    what: the array in words (e.g. "the skeleton video (T, H, W, 3) uint8");
    hint: what to do instead (e.g. "use a smaller --size"); available: bytes
    (default: :func:`available_bytes`; None there means no check).
    """
    need = int(itemsize)
    for n in shape:
        need *= int(n)
    if available is None:
        available = available_bytes()
    if available is not None and need > available:
        raise ArraySizeError(
            f"{what} of shape {tuple(int(n) for n in shape)} needs {need / GIB:.1f} GiB, "
            f"found {available / GIB:.1f} GiB of memory available; {hint}"
        )
