"""One owner of oscar's output: loggers, verbosity, progress bars and run log files.

Library code calls ``get_logger(__name__)`` and logs; only the CLI prints
results (on stdout). Every logger hangs under the root ``oscar`` logger
(``oscar_core.toyworld.cli`` → ``oscar.toyworld.cli``, ``oscar_zoo._fetch`` →
``oscar.zoo._fetch``), so one call silences, raises or redirects all of them.

Verbosity, set once:

* library use: ``$OSCAR_VERBOSITY`` (``debug``, ``info``, ``warning``, ``error``,
  ``critical``), else WARNING — as diffusers' ``DIFFUSERS_VERBOSITY``;
  :func:`set_verbosity` in code;
* the ``oscar`` command (:func:`configure_cli`): INFO (what a job is doing),
  ``-v`` DEBUG, ``-q`` WARNING, ``-qq`` ERROR; ``$OSCAR_VERBOSITY`` replaces the
  INFO default, ``-v``/``-q`` win over it.

Progress bars (:func:`progress_bar`, tqdm on stderr) are shown only when
stderr is a terminal and bars are enabled: ``--no-progress`` on any command,
:func:`disable_progress_bars` in code, or ``$OSCAR_DISABLE_PROGRESS_BARS=1``
(as huggingface_hub's ``HF_HUB_DISABLE_PROGRESS_BARS``) turn them off, and so
does ``-q`` (a quiet command draws no bars).

Long jobs keep a plain log beside their results with :func:`run_log`:
``RUN_DIR/logs/<job>-<UTC time>.log``, one timestamped line per record at
INFO and above whatever the console shows; its first line is the command
line, its last the result (:func:`log_result`) or the error that ended it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

__all__ = [
    "ROOT",
    "ENV_VERBOSITY",
    "ENV_DISABLE_PROGRESS",
    "get_logger",
    "set_verbosity",
    "get_verbosity",
    "verbosity_from_env",
    "configure_cli",
    "cli_output",
    "progress_bar",
    "progress_bars_enabled",
    "enable_progress_bars",
    "disable_progress_bars",
    "run_log",
    "log_result",
    "command_line",
    "set_command_line",
    "recorded_command",
]

ROOT = "oscar"
ENV_VERBOSITY = "OSCAR_VERBOSITY"
ENV_DISABLE_PROGRESS = "OSCAR_DISABLE_PROGRESS_BARS"
LEVELS = {
    "debug": logging.DEBUG,
    "info": logging.INFO,
    "warning": logging.WARNING,
    "error": logging.ERROR,
    "critical": logging.CRITICAL,
}
_FILE_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"

_verbosity: int | None = None  # None: not set in code yet (the environment or WARNING decides)
_progress_enabled: bool | None = None  # None: not set in code yet (the environment decides)


def _logger_name(name: str) -> str:
    for prefix, new in (
        ("oscar_core", ROOT),
        ("oscar_zoo", f"{ROOT}.zoo"),
        ("oscar_embodiments", f"{ROOT}.embodiments"),
    ):
        if name == prefix or name.startswith(prefix + "."):
            return new + name[len(prefix) :]
    if name == ROOT or name.startswith(ROOT + "."):
        return name
    return f"{ROOT}.{name}"


def get_logger(name: str = ROOT) -> logging.Logger:
    """The logger for module ``name`` (pass ``__name__``), a child of the ``oscar`` logger."""
    _root()
    return logging.getLogger(_logger_name(name))


def verbosity_from_env(default: int = logging.WARNING) -> int:
    """``$OSCAR_VERBOSITY`` as a logging level; ``default`` when unset.

    Raises ValueError naming the variable, the accepted words and the value found.
    """
    raw = os.environ.get(ENV_VERBOSITY, "").strip().lower()
    if not raw:
        return default
    if raw not in LEVELS:
        raise ValueError(f"${ENV_VERBOSITY}: expected one of {', '.join(LEVELS)}, found {raw!r}")
    return LEVELS[raw]


def _root() -> logging.Logger:
    root = logging.getLogger(ROOT)
    if not getattr(root, "_oscar_configured", False):
        root._oscar_configured = True
        root.setLevel(_verbosity if _verbosity is not None else verbosity_from_env())
    return root


def get_verbosity() -> int:
    """The level the ``oscar`` logger's console output is at (``logging.INFO`` …)."""
    if _verbosity is not None:
        return _verbosity
    return verbosity_from_env()


def _apply() -> None:
    """Logger level = the lowest level anything listens at (console or a run log)."""
    root = _root()
    level = get_verbosity()
    files = [h for h in root.handlers if isinstance(h, _RunLogHandler)]
    root.setLevel(min([level] + [h.level for h in files]))
    for h in root.handlers:
        if isinstance(h, _ConsoleHandler):
            h.setLevel(level)


def set_verbosity(level: int | str) -> None:
    """Set the console verbosity of every oscar logger (a logging level or a word of :data:`LEVELS`)."""
    global _verbosity
    if isinstance(level, str):
        if level.lower() not in LEVELS:
            raise ValueError(f"verbosity: expected one of {', '.join(LEVELS)}, found {level!r}")
        level = LEVELS[level.lower()]
    _verbosity = int(level)
    _apply()


class _ConsoleHandler(logging.Handler):
    """Writes to the *current* ``sys.stderr`` through ``tqdm.write``, so lines never break a progress bar."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            msg = self.format(record)
            from tqdm import tqdm

            tqdm.write(msg, file=sys.stderr)
        except Exception:  # noqa: BLE001 - logging must never raise into the caller
            self.handleError(record)


class _CLIFormatter(logging.Formatter):
    """The message alone for INFO and below; ``warning: …`` / ``error: …`` above."""

    def format(self, record: logging.LogRecord) -> str:
        msg = record.getMessage()
        if record.exc_info:
            msg += "\n" + self.formatException(record.exc_info)
        if record.levelno >= logging.WARNING:
            return f"{record.levelname.lower()}: {msg}"
        return msg


def configure_cli(verbose: int = 0, quiet: int = 0, *, progress: bool = True) -> int:
    """Set up output for the ``oscar`` command; returns the console level.

    verbose/quiet: how many ``-v`` / ``-q`` were given (module docstring).
    progress: False for ``--no-progress``. Safe to call more than once (tests
    call ``main`` many times): the console handler is replaced, not added again.
    """
    if verbose and quiet:
        raise ValueError("-v/--verbose and -q/--quiet: expected one of them, found both")
    if verbose:
        level = logging.DEBUG
    elif quiet:
        level = logging.WARNING if quiet == 1 else logging.ERROR
    else:
        level = verbosity_from_env(logging.INFO)
    root = _root()
    for h in [h for h in root.handlers if isinstance(h, _ConsoleHandler)]:
        root.removeHandler(h)
    handler = _ConsoleHandler()
    handler.setFormatter(_CLIFormatter())
    root.addHandler(handler)
    root.propagate = False  # the command owns stderr; no double lines through the root logger
    set_verbosity(level)
    if not progress or quiet:  # -q: warnings and results only, no bars
        disable_progress_bars()
    else:
        global _progress_enabled
        _progress_enabled = None  # back to the environment's say
    return level


@contextlib.contextmanager
def cli_output(verbose: int = 0, quiet: int = 0, *, progress: bool = True) -> Iterator[int]:
    """:func:`configure_cli` for the duration of one command, then the previous state back.

    ``oscar_core.cli.main`` runs inside it, so calling ``main`` from Python
    (tests, notebooks) leaves the ``oscar`` logger as it found it.
    """
    global _verbosity, _progress_enabled
    root = _root()
    saved = (_verbosity, _progress_enabled, root.propagate, list(root.handlers))
    try:
        yield configure_cli(verbose, quiet, progress=progress)
    finally:
        _verbosity, _progress_enabled, root.propagate = saved[:3]
        for h in [h for h in root.handlers if isinstance(h, _ConsoleHandler) and h not in saved[3]]:
            root.removeHandler(h)
        for h in saved[3]:
            if h not in root.handlers:
                root.addHandler(h)
        _apply()


def enable_progress_bars() -> None:
    """Show progress bars (still only when stderr is a terminal)."""
    global _progress_enabled
    _progress_enabled = True


def disable_progress_bars() -> None:
    """Never show progress bars (``--no-progress``)."""
    global _progress_enabled
    _progress_enabled = False


def progress_bars_enabled() -> bool:
    """Whether a bar would be drawn now: enabled (flag, code or environment) and stderr a terminal."""
    if _progress_enabled is False:
        return False
    if _progress_enabled is None and os.environ.get(ENV_DISABLE_PROGRESS, "").strip().lower() in ("1", "true", "yes"):
        return False
    isatty = getattr(sys.stderr, "isatty", None)
    return bool(isatty and isatty())


def progress_bar(
    iterable: Iterable | None = None,
    *,
    total: int | None = None,
    desc: str | None = None,
    unit: str = "it",
    leave: bool = True,
    enabled: bool | None = None,
    **kwargs,
):
    """A tqdm bar on stderr (rate and ETA), disabled per :func:`progress_bars_enabled`.

    enabled: False forces it off (e.g. ``--json`` output); None/True defer to
    :func:`progress_bars_enabled`. Returns the tqdm object (iterate it, or
    ``update(n)``; use it as a context manager to close it).
    """
    from tqdm.auto import tqdm

    on = progress_bars_enabled() and enabled is not False
    return tqdm(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        leave=leave,
        disable=not on,
        file=sys.stderr,
        dynamic_ncols=True,
        **kwargs,
    )


class _RunLogHandler(logging.FileHandler):
    """The plain log file of one run (:func:`run_log`); folder and file are made at the first record, which
    is preceded by the command line."""

    command: str = ""
    result: str | None = None

    def _open(self):
        Path(self.baseFilename).parent.mkdir(parents=True, exist_ok=True)
        stream = super()._open()
        stream.write(self.format(self._record(logging.INFO, "command: %s", self.command)) + self.terminator)
        return stream

    @staticmethod
    def _record(level: int, msg: str, *args) -> logging.LogRecord:
        return logging.LogRecord(ROOT, level, __file__, 0, msg, args, None)


_RUN_LOGS: list[_RunLogHandler] = []  # the open run logs, innermost last


_COMMAND: list[str] | None = None  # the command being run (set_command_line), else sys.argv


def set_command_line(argv: list[str] | None) -> None:
    """Name the command this process runs now (``["oscar", "train", ...]``; None: ``sys.argv``) for run logs."""
    global _COMMAND
    _COMMAND = None if argv is None else [str(a) for a in argv]


def recorded_command() -> list[str] | None:
    """The command :func:`set_command_line` named (``["oscar", "train", ...]``), or None outside a command."""
    return None if _COMMAND is None else list(_COMMAND)


def command_line(argv: list[str] | None = None) -> str:
    """A command line as a shell would take it back (``oscar train x.yaml --set steps=30``); default: the one
    :func:`set_command_line` named, else this process's ``sys.argv``."""
    import shlex

    argv = list((_COMMAND or sys.argv) if argv is None else argv)
    if argv:
        argv[0] = Path(argv[0]).name
    return " ".join(shlex.quote(a) for a in argv)


def log_result(text: str) -> None:
    """Set the final line of the innermost open :func:`run_log` (``result: <text>``); nothing without one."""
    if _RUN_LOGS:
        _RUN_LOGS[-1].result = text


@contextlib.contextmanager
def run_log(folder, job: str, *, level: int = logging.INFO, command: str | None = None) -> Iterator[Path]:
    """Copy every oscar log record at ``level`` and above to ``folder/logs/<job>-<UTC>.log`` while inside.

    The file is plain text, one ``<ISO time> <LEVEL> <logger>: <message>``
    line per record, appended as it happens (a killed job keeps what it
    logged); it and its folder are created at the first record, so a job
    rejected before it logs anything leaves nothing behind. The first line is
    ``command: <command>`` (default: this process's :func:`command_line`); the
    last is ``result: …`` (:func:`log_result`, else ``finished``) with the
    wall seconds, or the exception that ended the job. Yields the file's path.
    """
    logs = Path(folder) / "logs"
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    path = logs / f"{job}-{stamp}.log"
    k = 1
    while path.exists():  # two runs in the same second: never overwrite
        path = logs / f"{job}-{stamp}-{k}.log"
        k += 1
    handler = _RunLogHandler(path, encoding="utf-8", delay=True)  # a job rejected at once leaves no folder
    formatter = logging.Formatter(_FILE_FORMAT, datefmt="%Y-%m-%dT%H:%M:%S")
    formatter.converter = time.gmtime
    handler.setFormatter(formatter)
    handler.setLevel(level)
    handler.command = command_line() if command is None else command
    root = _root()
    root.addHandler(handler)
    _RUN_LOGS.append(handler)
    _apply()
    t0 = time.perf_counter()
    try:
        yield path
    except BaseException as exc:
        if handler.stream is not None:  # the job had started logging: say in its log why it stopped
            handler.emit(handler._record(logging.ERROR, "stopped by %s: %s", type(exc).__name__, exc))
        raise
    else:  # a finished job always leaves its log: the command line and the result
        handler.emit(
            handler._record(logging.INFO, "result: %s (%.1f s)", handler.result or "finished", time.perf_counter() - t0)
        )
    finally:
        _RUN_LOGS.remove(handler)
        root.removeHandler(handler)
        handler.close()
        _apply()
