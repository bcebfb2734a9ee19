"""Ctrl-C: one line and exit status 130, with worker processes stopped, not a traceback per process.

A terminal sends SIGINT to the whole foreground process group, so every pool
worker would raise its own ``KeyboardInterrupt`` and print its own traceback,
and ``ProcessPoolExecutor.__exit__`` would then wait for every queued task.
Instead workers ignore SIGINT (:func:`worker_ignores_interrupt`, called from a
pool's initializer) and the parent, which gets the ``KeyboardInterrupt``, stops
them (:func:`stop_pool`) and leaves the message to the CLI (:func:`message`).
Finished work is already on disk (completion records, atomic renames), so the
same command resumes. The line says so only when it is true: a command whose
parser sets ``_resumes=False`` (one video: ``oscar rollout``, a single
``oscar render``; or a function of the parsed arguments) starts over when run
again, and an output that holds nothing yet has nothing kept.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time

__all__ = [
    "EXIT_INTERRUPTED",
    "Interrupted",
    "interrupted",
    "message",
    "noting_interrupts",
    "output_of",
    "report",
    "stop_pool",
    "worker_ignores_interrupt",
]

EXIT_INTERRUPTED = 130  # 128 + SIGINT, what shells report for a command stopped by Ctrl-C
GRACE_S = 3.0  # seconds busy threads get to end after Ctrl-C before the process exits without them


_NOTED = {"sigint": False}


def _note_and_raise(signum, frame):
    _NOTED["sigint"] = True
    raise KeyboardInterrupt


@contextlib.contextmanager
def noting_interrupts():
    """While the block runs, SIGINT raises ``KeyboardInterrupt`` as usual and is also noted (:func:`interrupted`).

    Some libraries catch the ``KeyboardInterrupt`` and raise their own error
    (torch's checkpoint writer turns it into a ``RuntimeError`` inside a
    ``CheckpointException``); the note lets the CLI still report Ctrl-C.
    Only in the main thread (elsewhere signal handlers cannot be set: no-op).
    """
    _NOTED["sigint"] = False
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, _note_and_raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def interrupted() -> bool:
    """Whether SIGINT arrived inside the current :func:`noting_interrupts` block."""
    return _NOTED["sigint"]


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


class Interrupted(KeyboardInterrupt):
    """Ctrl-C in a command that resumes another way than by running it again (``oscar train``: ``--resume``).

    where: what holds the finished work; resume: the command that resumes it.
    """

    def __init__(self, where: str, resume: str):
        super().__init__(where, resume)
        self.where, self.resume = where, resume


def message(where: str | None, resume: str | None = None) -> str:
    """The one line printed on Ctrl-C; ``where``: the command's output folder or file, if it has one;
    ``resume``: the command that resumes (default: the same command)."""
    kept = f"finished work is kept in {where}" if where else "finished work is kept"
    how = f"run {resume} to resume" if resume else "run the same command to resume"
    return f"interrupted; {kept}; {how}"


def report(exc: KeyboardInterrupt, args=None) -> int:
    """Print the Ctrl-C line for ``exc`` (an :class:`Interrupted` or a plain ``KeyboardInterrupt``); returns 130.

    When threads of a pool are still busy after ``GRACE_S`` (a judge request
    in flight for up to its timeout), the interpreter would wait for them
    before exiting: then this exits the process, with status 130, after
    flushing output.
    Their work is not finished work; whatever finished is already on disk.
    """
    import os
    import sys
    import threading

    if isinstance(exc, Interrupted):
        line = message(exc.where, exc.resume)
    else:
        line = _line_for(args)
    print(line, file=sys.stderr)

    def busy():
        return [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon and t.is_alive()]

    deadline = time.monotonic() + GRACE_S  # a stopped process pool's manager thread ends in well under a second
    for t in busy():
        t.join(max(0.0, deadline - time.monotonic()))
    if busy():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(EXIT_INTERRUPTED)
    return EXIT_INTERRUPTED


def _resumes(args) -> bool:
    """Whether running the parsed command again resumes it (the parser's ``_resumes``: a bool or a function of
    the arguments; default True: the stages, whose finished shards and cells are kept)."""
    r = getattr(args, "_resumes", True)
    return bool(r(args)) if callable(r) else bool(r)


def holds_work(where: str) -> bool:
    """Whether the output ``where`` holds anything a rerun could keep: a file, or a folder with an entry other
    than ``logs/`` and writers' ``.*.tmp*`` temporaries (a URL is trusted to)."""
    import os
    from pathlib import Path

    if "://" in where:
        return True
    p = Path(where)
    if p.is_file():
        return True
    if not p.is_dir():
        return False
    return any(e != "logs" and not (e.startswith(".") and ".tmp" in e) for e in os.listdir(p))


def _line_for(args) -> str:
    where = output_of(args) if args is not None else None
    if where is None:
        return message(None)
    if not _resumes(args):
        return f"interrupted; nothing was written to {where}; running the command again starts over"
    if not holds_work(where):
        return f"interrupted before any work finished; nothing was written to {where}"
    return message(where)


def output_of(args) -> str | None:
    """The output a parsed ``oscar`` command writes (``--out``, else a positional run folder), or None."""
    for name in ("out", "run", "run_dir"):
        value = getattr(args, name, None)
        if isinstance(value, str) and value:
            return value
    return None
