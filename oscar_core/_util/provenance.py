"""What made an output: the command line, the date and oscar's version (shown on every report page).

The ``oscar`` command records its arguments once (:func:`set_command`, called
by :func:`oscar_core.cli.main`); library code asks :func:`provenance`. A page
written through the Python API says so and names the script (``sys.argv``).
"""

from __future__ import annotations

import shlex
import sys
import time

__all__ = ["set_command", "command_line", "provenance"]

_command: list[str] | None = None


def set_command(argv) -> None:
    """Record the arguments of the running ``oscar`` command (without the program name)."""
    global _command
    _command = [str(a) for a in argv]


def command_line() -> str:
    """``oscar <args>`` as a shell would take it, or ``python API (<script args>)`` outside the command."""
    if _command is not None:
        return shlex.join(["oscar", *_command])
    return f"python API ({shlex.join(sys.argv) or 'interactive'})"


def provenance() -> dict:
    """``{"date": UTC ISO 8601 to the second, "command": command_line(), "version": oscar's version}``."""
    from .. import __version__

    return {
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "command": command_line(),
        "version": __version__,
    }
