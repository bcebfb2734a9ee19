"""How many threads or worker processes this machine can give now, and a warning when a job asks for more.

On a shared machine a CPU-bound job with more threads than idle cores does
not go faster, it goes much slower: ``oscar toyworld train-vae --threads 2``
measured 27–46 s per step on a busy 2-core machine against 2.7–5 s with one
thread. So defaults are taken from what is idle, not from the core count:

* :func:`available_cpus`: the cores this process may run on (its CPU
  affinity, which containers and ``taskset`` restrict), else ``os.cpu_count()``;
* :func:`idle_cpus`: those minus the 1-minute load average (runnable
  processes, this one excluded when it is already busy), at least 1;
* :func:`default_threads` = :func:`idle_cpus` — the default of
  ``toyworld train-vae --threads`` and of the data stages' ``--workers``
  (each worker process then runs one torch thread).

:func:`check_threads` warns with :class:`ThreadOversubscriptionWarning` (a
``warnings`` category users can filter) when a request exceeds the idle cores.
"""

from __future__ import annotations

import os
import warnings

__all__ = ["ThreadOversubscriptionWarning", "available_cpus", "idle_cpus", "default_threads", "check_threads"]


class ThreadOversubscriptionWarning(UserWarning):
    """More threads or workers were asked for than the machine has idle cores."""


def available_cpus() -> int:
    """Cores this process may run on (CPU affinity), else ``os.cpu_count()``; at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def idle_cpus() -> int:
    """Available cores minus the 1-minute load average (rounded), between 1 and :func:`available_cpus`."""
    n = available_cpus()
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):  # no load average (Windows): trust the core count
        return n
    return max(1, min(n, n - int(round(load))))


def default_threads() -> int:
    """The thread (or worker) count a job should default to now: :func:`idle_cpus`."""
    return idle_cpus()


def check_threads(requested: int, what: str) -> None:
    """Warn when ``requested`` threads/workers for ``what`` (a flag name) exceed the idle cores."""
    idle = idle_cpus()
    if requested > idle:
        warnings.warn(f"{what}: {requested} requested, but only {idle} of {available_cpus()} cores are idle now "
                      f"(load average {os.getloadavg()[0]:.1f}); on a busy machine more threads than idle cores "
                      f"run much slower (toyworld train-vae: 27-46 s per step with 2 threads against 2.7-5 s with 1 "
                      f"on a busy 2-core machine). Leave the flag out to use what is idle.",
                      ThreadOversubscriptionWarning, stacklevel=2)
