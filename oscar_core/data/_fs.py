"""fsspec helpers of the data pipeline: one place that turns a path or URL into a filesystem.

Every stage reads and writes through these, so a local folder, ``file://``,
``memory://`` (tests) or ``s3://`` (with s3fs installed) work the same way.
Writes are atomic where the filesystem allows: the bytes go to a hidden
temporary name beside the target, which is then moved onto it (a rename on
local disks); readers only ever see complete files. The temporary's name
carries the writer's pid, and on a local disk the first write of a process
into a folder removes the temporaries of dead processes there
(:func:`oscar_core._util.atomic.sweep_dead_temporaries`).
"""

from __future__ import annotations

import os
import posixpath
import uuid

__all__ = [
    "url_to_fs",
    "join",
    "write_bytes_atomic",
    "read_bytes",
    "exists",
    "listdir",
    "local_path",
    "is_local",
    "process_local",
    "put_tree",
]


def url_to_fs(url: str):
    """(filesystem, path within it) for a local path or an fsspec URL.

    An unknown protocol is a ValueError naming the URL; a known one whose
    package is missing (``s3://`` without s3fs) an ImportError naming the
    package to install.
    """
    import fsspec
    from fsspec.registry import known_implementations

    url = str(url)
    try:
        return fsspec.core.url_to_fs(url)
    except ImportError as exc:
        proto = url.split("://", 1)[0]
        impl = known_implementations.get(proto, {}).get("class", "")
        package = impl.split(".", 1)[0] or "the filesystem's package"
        raise ImportError(
            f"{url}: the {proto}:// filesystem needs the Python package {package!r} "
            f"(pip install {package}); fsspec says: {exc}"
        ) from None
    except ValueError as exc:
        if "Protocol not known" not in str(exc):
            raise
        proto = url.split("://", 1)[0]
        raise ValueError(
            f"{url}: expected a local path or an fsspec URL, found the unknown protocol {proto!r} "
            f"(known: file, memory, s3, gcs, az, hdfs, … see fsspec.available_protocols())"
        ) from None


def process_local(url: str) -> bool:
    """True for a filesystem only this process sees (``memory://``): worker processes would write elsewhere."""
    fs, _ = url_to_fs(url)
    protocols = fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,)
    return "memory" in protocols


def put_tree(local_dir: str, url: str, last: tuple[str, ...] = ()) -> None:
    """Copy the files under a local folder to ``url`` (a folder), replacing what is there; the files named in
    ``last`` (paths relative to the folder) are copied after all others, so a reader that waits for them never
    sees a partial folder."""
    import os

    fs, root = url_to_fs(url)
    if fs.exists(root):
        fs.rm(root, recursive=True)
    files = []
    for base, _, names in os.walk(local_dir):
        for name in names:
            files.append(os.path.relpath(os.path.join(base, name), local_dir).replace(os.sep, "/"))
    files.sort(key=lambda f: (f in last, last.index(f) if f in last else 0, f))
    for rel in files:
        target = posixpath.join(root, rel)
        fs.makedirs(posixpath.dirname(target), exist_ok=True)
        fs.put_file(os.path.join(local_dir, rel), target)


def join(url: str, *parts: str) -> str:
    """Join path parts onto a local path or URL with '/'."""
    url = str(url)
    if "://" in url:
        proto, rest = url.split("://", 1)
        return f"{proto}://{posixpath.join(rest, *parts)}"
    return posixpath.join(url, *parts)


def write_bytes_atomic(url: str, data: bytes) -> None:
    """Write ``data`` to ``url``: to a temporary name in the same folder, then moved into place."""
    fs, path = url_to_fs(url)
    folder = posixpath.dirname(path)
    fs.makedirs(folder, exist_ok=True)
    if _is_local_fs(fs):
        from .._util.atomic import sweep_once

        sweep_once(folder)
    # the writer's pid in the name: the next writer into this folder sweeps it if this process dies first
    tmp = posixpath.join(folder, f".{posixpath.basename(path)}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp")
    with fs.open(tmp, "wb") as f:
        f.write(data)
    try:
        fs.mv(tmp, path)
    except BaseException:
        try:
            fs.rm(tmp)
        except FileNotFoundError:
            pass
        raise


def read_bytes(url: str) -> bytes:
    fs, path = url_to_fs(url)
    with fs.open(path, "rb") as f:
        return f.read()


def exists(url: str) -> bool:
    fs, path = url_to_fs(url)
    return bool(fs.exists(path))


def listdir(url: str) -> list[str]:
    """Base names of the entries of a folder (empty when it does not exist), sorted."""
    fs, path = url_to_fs(url)
    if not fs.exists(path):
        return []
    return sorted(posixpath.basename(p.rstrip("/")) for p in fs.ls(path, detail=False))


def _is_local_fs(fs) -> bool:
    protocols = fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,)
    return "file" in protocols or "local" in protocols


def is_local(url: str) -> bool:
    """True for a local path or a ``file://`` URL."""
    fs, _ = url_to_fs(url)
    return _is_local_fs(fs)


def local_path(url: str) -> str:
    """The local path of a local path or ``file://`` URL; ValueError naming the URL for any other filesystem."""
    url = str(url)
    fs, path = url_to_fs(url)
    protocols = fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,)
    if "file" not in protocols and "local" not in protocols:
        raise ValueError(
            f"{url}: expected a local folder or a file:// URL here (this output is written with local "
            f"file APIs), found protocol {protocols[0]!r}"
        )
    return path
