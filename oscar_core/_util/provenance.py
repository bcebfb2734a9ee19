"""What made an output: the command line, the date and oscar's version (shown on every report page).

The ``oscar`` command records its arguments once
(:func:`oscar_core._util.log.set_command_line`, called by :func:`oscar_core.cli.main`; the run logs read the
same record); library code asks :func:`provenance`. A page written through the Python API says so and names the
script (``sys.argv``).
"""

from __future__ import annotations

import shlex
import sys
import time

from .log import recorded_command

__all__ = ["command_line", "provenance"]


def command_line() -> str:
    """``oscar <args>`` as a shell would take it, or ``python API (<script args>)`` outside the command."""
    argv = recorded_command()
    if argv is not None:
        return shlex.join(argv)
    return f"python API ({shlex.join(sys.argv) or 'interactive'})"


def provenance() -> dict:
    """``{"date": UTC ISO 8601 to the second, "command": command_line(), "version": oscar's version}``."""
    from .. import __version__

    return {
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "command": command_line(),
        "version": __version__,
    }
