"""End the ``oscar`` process once its command has returned, without the interpreter's module teardown.

After a rollout the interpreter holds torch, diffusers, transformers and sympy: tearing those modules down
object by object took about 1 s of a 7 s one-chunk ``oscar rollout`` on this CPU (benchmarks/cli_rollout.py,
column ``exit``). Nothing the command wrote depends on that teardown, so :func:`exit_process` does what the
interpreter's own shutdown does first — wait for non-daemon threads, run the ``atexit`` callbacks (logging's
flush, ``weakref.finalize`` clean-ups such as temporary folders, worker-pool shutdowns, coverage's data file),
flush stdout and stderr — and then ends the process with ``os._exit(code)``.

Only the command-line entry points call it (``oscar`` and ``python -m oscar_core.cli``); ``oscar_core.cli.main``
called from Python returns as before. ``OSCAR_FULL_EXIT=1`` keeps the interpreter's full shutdown (for tools that
need every object finalised).
"""

from __future__ import annotations

import atexit
import os
import sys
import threading

__all__ = ["exit_process"]


def exit_process(code: int | None) -> None:
    """End this process with ``code`` (None → 0) after threads, ``atexit`` callbacks and a flush; never returns
    unless ``OSCAR_FULL_EXIT`` is set (then it raises ``SystemExit(code)`` for the usual shutdown)."""
    if os.environ.get("OSCAR_FULL_EXIT", "").strip() not in ("", "0"):
        raise SystemExit(code)
    code = 0 if code is None else int(code)
    main = threading.main_thread()
    shutdown = getattr(threading, "_shutdown", None)
    if shutdown is not None and threading.current_thread() is main:
        # the interpreter's own first step: threading's exit hooks (they stop the workers of thread pools left
        # open, e.g. concurrent.futures'), then a join of every non-daemon thread
        shutdown()
    else:
        for thread in threading.enumerate():
            if thread is not main and not thread.daemon and thread is not threading.current_thread():
                thread.join()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError):  # a closed pipe (`oscar ... | head`) or a closed stream: nothing to flush to
            code = code or 1
    os._exit(code)
