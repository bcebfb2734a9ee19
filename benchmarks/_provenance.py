"""Where and when a benchmark ran: the ``provenance`` block every benchmarks/*.py JSON carries.

``docs/benchmarks.md`` (written by ``benchmarks/make_docs.py`` from ``benchmarks/measured/*.json``) shows it above
each table: the UTC date, the commit measured (``+dirty`` when its code differed from it), the machine and the
command line.
"""

from __future__ import annotations

import datetime
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def _git(*args: str) -> str | None:
    try:
        proc = subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return proc.stdout.strip() if proc.returncode == 0 else None


#: what a measurement depends on: a change elsewhere (docs, tests) does not make the checkout differ from its commit
CODE = (
    "oscar_core",
    "zoo",
    "embodiments",
    "examples",
    "benchmarks",
    "configs",
    "pyproject.toml",
    "requirements-ci.txt",
)


def commit() -> str:
    """The checkout's commit (12 hex digits), ``+dirty`` if tracked files of :data:`CODE` differ from it;
    ``unknown`` outside git."""
    head = _git("rev-parse", "--short=12", "HEAD")
    if head is None:
        return "unknown"
    return head + ("+dirty" if _git("status", "--porcelain", "--untracked-files=no", "--", *CODE) else "")


def machine(device: str | None = None, gpu: str | None = None) -> dict:
    """The processor, CPU count, 1-minute load average (when the result is written), Python and (if imported) torch
    version; the GPU's name when ``gpu`` is given, or when torch is imported and ``device`` is CUDA or the process
    has initialised CUDA."""
    out = {
        "processor": platform.processor() or platform.machine(),
        "system": platform.system(),
        "cpus": os.cpu_count(),
        "load_average": round(os.getloadavg()[0], 2),
        "python": platform.python_version(),
    }
    torch = sys.modules.get("torch")
    if torch is not None:
        out["torch"] = torch.__version__
        on_cuda = device is not None and str(device).startswith("cuda")
        if gpu is None and torch.cuda.is_available() and (on_cuda or torch.cuda.is_initialized()):
            # a script whose --device is the CPU may still have measured on the GPU (rollout.py --measure cuda)
            gpu = torch.cuda.get_device_name(torch.device(device) if on_cuda else torch.cuda.current_device())
    if gpu:
        out["gpu"] = gpu
    return out


def command() -> str:
    """The command line that is running, as a person would type it from the repository root."""
    script = Path(sys.argv[0]).resolve()
    shown = script.relative_to(REPO).as_posix() if script.is_relative_to(REPO) else sys.argv[0]
    return shlex.join(["python", shown, *sys.argv[1:]])


def provenance(device: str | None = None, gpu: str | None = None) -> dict:
    """``{"date": UTC ISO 8601, "commit": …, "machine": {…}, "command": …}`` (see :func:`commit`, :func:`machine`
    and :func:`command`)."""
    date = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0).isoformat()
    return {"date": date, "commit": commit(), "machine": machine(device, gpu), "command": command()}


def with_provenance(result: dict, device: str | None = None, gpu: str | None = None) -> dict:
    """``result`` with the ``provenance`` block first."""
    return {"provenance": provenance(device, gpu), **result}
