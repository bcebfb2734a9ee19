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

Every command that runs torch takes its thread count from one function,
:func:`choose_threads`: ``--threads N`` if given, else ``$OSCAR_NUM_THREADS``,
else :func:`default_threads`. :func:`use_threads` applies the choice to
torch's intra-op and inter-op pools and sets ``OMP_WAIT_POLICY=PASSIVE``
(unless the user set it) so that OpenMP threads waiting at a barrier sleep
instead of spinning on cores other jobs need; that variable is read when the
OpenMP runtime starts, so the ``oscar`` command sets it before torch is
imported (:func:`passive_openmp`).
"""

from __future__ import annotations

import os
import sys
import warnings

from ..errors import OscarError
from .log import get_logger

__all__ = [
    "ThreadOversubscriptionWarning",
    "ENV_THREADS",
    "available_cpus",
    "idle_cpus",
    "default_threads",
    "check_threads",
    "choose_threads",
    "use_threads",
    "passive_openmp",
]

ENV_THREADS = "OSCAR_NUM_THREADS"


class ThreadOversubscriptionWarning(UserWarning):
    """More threads or workers were asked for than the machine has idle cores."""


def available_cpus() -> int:
    """Cores this process may run on (CPU affinity), else ``os.cpu_count()``; at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _load() -> float | None:
    try:
        return os.getloadavg()[0]
    except (AttributeError, OSError):  # no load average (Windows)
        return None


def idle_cpus(*, cpus: int | None = None, load: float | None = None) -> int:
    """Available cores minus the 1-minute load average (rounded), between 1 and :func:`available_cpus`.

    cpus, load: a core count and a load average to use instead of this
    machine's (tests); without a load average the core count is trusted.
    """
    n = available_cpus() if cpus is None else max(1, int(cpus))
    load = _load() if load is None else load
    if load is None:
        return n
    return max(1, min(n, n - int(round(load))))


def default_threads() -> int:
    """The thread (or worker) count a job should default to now: :func:`idle_cpus`."""
    return idle_cpus()


def choose_threads(
    requested: int | None = None, *, env: dict | None = None, cpus: int | None = None, load: float | None = None
) -> int:
    """The torch thread count of a command: ``requested`` (``--threads``), else ``$OSCAR_NUM_THREADS``, else a
    ``$OMP_NUM_THREADS`` the user set, else the cores idle now (:func:`idle_cpus`; ``cpus`` and ``load`` stand in
    for this machine's in tests; ``env`` for ``os.environ``).

    Raises :class:`~oscar_core.errors.OscarError` for a ``$OSCAR_NUM_THREADS`` that is not a positive integer.
    """
    if requested is not None:
        return int(requested)
    env = os.environ if env is None else env
    text = env.get(ENV_THREADS, "").strip()
    if text:
        if not text.isdigit() or int(text) < 1:
            raise OscarError(f"${ENV_THREADS}: expected a positive integer (torch threads), found {text!r}")
        return int(text)
    omp = env.get("OMP_NUM_THREADS", "").strip()
    if omp.isdigit() and int(omp) >= 1:
        return int(omp)
    return idle_cpus(cpus=cpus, load=load)


def passive_openmp(env: dict | None = None) -> None:
    """``OMP_WAIT_POLICY=PASSIVE`` unless set: idle OpenMP threads sleep rather than spin (read when OpenMP starts)."""
    env = os.environ if env is None else env
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def use_threads(requested: int | None = None, *, import_torch: bool = True) -> int:
    """Apply :func:`choose_threads` to torch (intra-op and inter-op pools); returns the count.

    Before torch is imported (``import_torch=False`` keeps it so) the count
    goes to ``OMP_NUM_THREADS``, which torch reads when it loads. The
    inter-op pool can be sized only before its first use: later calls leave it.
    """
    n = choose_threads(requested)
    passive_openmp()
    load = _load()
    get_logger(__name__).debug(
        "torch threads: %d (%s; %d cores available, load average %s, OMP_WAIT_POLICY=%s)",
        n,
        "--threads" if requested is not None else "automatic",
        available_cpus(),
        "unknown" if load is None else f"{load:.2f}",
        os.environ.get("OMP_WAIT_POLICY"),
    )
    torch = sys.modules.get("torch")
    if torch is None and import_torch:
        import torch
    if torch is None:
        os.environ["OMP_NUM_THREADS"] = str(n)
        return n
    torch.set_num_threads(n)
    try:
        torch.set_num_interop_threads(n)
    except RuntimeError:  # already sized or started in this process (a second command in one process)
        pass
    return n


def check_threads(requested: int, what: str) -> None:
    """Warn when ``requested`` threads/workers for ``what`` (a flag name) exceed the idle cores."""
    idle = idle_cpus()
    if requested > idle:
        warnings.warn(
            f"{what}: {requested} requested, but only {idle} of {available_cpus()} cores are idle now "
            f"(load average {os.getloadavg()[0]:.1f}); on a busy machine more threads than idle cores "
            f"run much slower (toyworld train-vae: 27-46 s per step with 2 threads against 2.7-5 s with 1 "
            f"on a busy 2-core machine). Leave the flag out to use what is idle.",
            ThreadOversubscriptionWarning,
            stacklevel=2,
        )


def threads_option(parser, what: str = "torch CPU threads"):
    """Add ``--threads N`` (default: :func:`choose_threads`) to an ``argparse`` parser; the ``oscar`` command applies
    it with :func:`use_threads` before the sub-command runs. Returns the action."""
    from .arg_types import count

    action = parser.add_argument(
        "--threads",
        type=count(1),
        default=None,
        help=f"{what} (default: ${ENV_THREADS}, else the cores idle now, at least 1; on a "
        "busy machine more threads than idle cores run much slower)",
    )
    action.oscar_threads = True
    return action
