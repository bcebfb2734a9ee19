"""What a resumable stage's output depends on (its fingerprint), and worker pools that neither hang nor outlive us.

Fingerprints
    A resumable stage (each ``oscar data`` stage, a batch render, ``eval run``,
    ``toyworld rollout``) records beside its completion records the parts its
    output depends on — the input's identity, the effective settings, the
    model (name and revision), and a format version — and their sha256
    (:func:`fingerprint`). A re-run computes the parts again: equal, finished
    work is skipped; different, the stage either recomputes (its completion
    records are void) or refuses with :class:`StageChanged`, whose message names
    what changed (:func:`changes`) and the option that redoes the stage. Work
    done under other settings is never reported as "already done".

Worker pools
    :func:`pool_context` is a fork-server context (spawn where there is none):
    a new worker never inherits this process's threads or locks, so a pool
    can be made again and again, and after torch, tqdm or OpenCV started
    threads, without the hang a plain ``fork`` risks. :func:`watch_parent`
    (a pool's initializer) makes each worker exit when the process that made
    the pool dies, even by ``kill -9`` (a worker's own parent is the fork
    server, so it watches the pool's owner by pid).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any, Literal

from ..errors import OscarError

__all__ = [
    "FORMAT_VERSION",
    "EngineName",
    "StageChanged",
    "changes",
    "check_stage",
    "fingerprint",
    "model_identity",
    "pool_context",
    "watch_parent",
    "worker_initializer",
]

#: where a stage's work runs: a local process pool (or this process), or Ray tasks / actors
EngineName = Literal["local", "ray"]

FORMAT_VERSION = 1  # bump when a stage's stored output changes meaning; every stage then recomputes


class StageChanged(OscarError, ValueError):
    """A stage's output was made under other inputs or settings than this run's, and the stage refuses to mix them."""


def _canonical(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _canonical(v) for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    if isinstance(value, float) and math.isnan(value):
        return "nan"
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


def fingerprint(parts: Mapping[str, Any]) -> str:
    """sha256 (hex) of ``parts`` as canonical JSON (keys sorted, tuples as lists, other objects as ``str``)."""
    text = json.dumps(_canonical(parts), sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def changes(old: Mapping[str, Any] | None, new: Mapping[str, Any], prefix: str = "") -> list[str]:
    """Sentences naming what differs between two fingerprint part trees, e.g. ``settings.min_length: 70 -> 40``."""
    if old is None:
        return ["no fingerprint recorded (made by an older oscar)"]
    old, new = _canonical(old), _canonical(new)
    out: list[str] = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key, "<absent>"), new.get(key, "<absent>")
        if a == b:
            continue
        name = f"{prefix}{key}"
        if isinstance(a, dict) and isinstance(b, dict):
            out += changes(a, b, f"{name}.")
        else:
            out.append(f"{name}: {_short(a)} -> {_short(b)}")
    return out


def model_identity(spec, revision: str | None = None) -> str:
    """A string that changes when a world model's weights can: a folder's ``oscar_manifest.json`` sha256
    (``folder-manifest:<hex>``), else ``name@revision`` (``@pinned``: the zoo's pinned revision)."""
    from pathlib import Path

    p = Path(str(spec))
    manifest = p / "oscar_manifest.json"
    if p.is_dir() and manifest.is_file():
        with open(manifest, "rb") as f:
            return f"folder-manifest:{hashlib.file_digest(f, 'sha256').hexdigest()}"
    return f"{spec}@{revision or 'pinned'}"


def check_stage(folder, parts: Mapping[str, Any], *, redo: str) -> None:
    """Refuse to add to a local output ``folder`` made under other ``parts``; else record them.

    ``folder/fingerprint.json`` holds the parts of the run that wrote the
    folder. Absent (a new folder), it is written; equal, nothing happens;
    different, :class:`StageChanged` names every change and ``redo`` (the
    option or step that redoes the stage, e.g. "use another --out").
    """
    from pathlib import Path

    from .atomic import atomic_write_bytes

    path = Path(folder) / "fingerprint.json"
    new = fingerprint(parts)
    if path.is_file():
        try:
            old = json.loads(path.read_text())
        except (OSError, ValueError):
            old = None
        if isinstance(old, dict) and old.get("fingerprint") == new:
            return
        what = changes(old.get("parts") if isinstance(old, dict) else None, parts)
        raise StageChanged(
            f"{folder}: expected output of the same inputs and settings as this run, found one made "
            f"under others ({'; '.join(what)}); {redo}"
        )
    Path(folder).mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, json.dumps({"fingerprint": new, "parts": _canonical(parts)}, indent=1).encode())


def _short(v: Any) -> str:
    text = json.dumps(v) if not isinstance(v, str) else v
    return text if len(text) <= 60 else text[:28] + "…" + text[-28:]


# ----------------------------------------------------------------------- pools


def pool_context(preload: Sequence[str] = ()):
    """A multiprocessing context for worker pools: a fork server (``preload`` modules imported once in it, then
    inherited by every worker it forks) where the platform has one, else spawn."""
    import multiprocessing as mp

    if "forkserver" in mp.get_all_start_methods():
        ctx = mp.get_context("forkserver")
        if preload:
            ctx.set_forkserver_preload(list(preload))
        return ctx
    return mp.get_context("spawn")


def watch_parent(parent_pid: int, interval: float = 0.25) -> threading.Thread:
    """Exit this process (status 1, no clean-up) within ``interval`` seconds of process ``parent_pid`` ending.

    Called in a pool worker with the pid of the process that made the pool.
    Polls ``os.kill(pid, 0)`` from a daemon thread; on Linux the thread also
    exits when this process's parent changes (a forked worker whose parent died
    is adopted by init). Returns the thread.
    """
    from .atomic import pid_alive

    ppid = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(interval)
            if not pid_alive(parent_pid) or (ppid == parent_pid and os.getppid() != ppid):
                os._exit(1)

    t = threading.Thread(target=watch, name="oscar-parent-watch", daemon=True)
    t.start()
    return t


def worker_initializer(parent_pid: int, *then) -> None:
    """A pool initializer: :func:`watch_parent` (``parent_pid``), then each callable of ``then``."""
    watch_parent(parent_pid)
    for fn in then:
        fn()
