"""Ctrl-C: one line and exit status 130, with worker processes stopped, not a traceback per process.

A terminal sends SIGINT to the whole foreground process group, so every pool
worker would raise its own ``KeyboardInterrupt`` and print its own traceback,
and ``ProcessPoolExecutor.__exit__`` would then wait for every queued task.
Instead workers ignore SIGINT (:func:`worker_ignores_interrupt`, called from a
pool's initializer) and the parent, which gets the ``KeyboardInterrupt``, stops
them (:func:`stop_pool`) and leaves the message to the CLI (:func:`message`).
Finished work is already on disk (completion records, atomic renames), so the
same command resumes.
"""

from __future__ import annotations

import signal

__all__ = ["EXIT_INTERRUPTED", "message", "output_of", "stop_pool", "worker_ignores_interrupt"]

EXIT_INTERRUPTED = 130  # 128 + SIGINT, what shells report for a command stopped by Ctrl-C


def worker_ignores_interrupt() -> None:
    """In a pool worker: leave SIGINT to the parent process (it stops the pool)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def stop_pool(pool) -> None:
    """Cancel the queued tasks of a ``concurrent.futures.ProcessPoolExecutor`` and terminate its workers now.

    ``shutdown(wait=True)``, what leaving the ``with`` block does, would first
    run every queued task. Python < 3.14 has no public way to terminate the
    workers, so this reads the executor's process table (absent: nothing to do).
    """
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(timeout=5)


def message(where: str | None) -> str:
    """The one line printed on Ctrl-C; ``where``: the command's output folder or file, if it has one."""
    kept = f"finished work is kept in {where}" if where else "finished work is kept"
    return f"interrupted; {kept}; run the same command to resume"


def output_of(args) -> str | None:
    """The output a parsed ``oscar`` command writes (``--out``, else a positional run folder), or None."""
    for name in ("out", "run", "run_dir"):
        value = getattr(args, name, None)
        if isinstance(value, str) and value:
            return value
    return None
