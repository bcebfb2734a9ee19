"""Which torch devices this machine has: one check for the CLIs' ``--device`` and the Python API's ``device=``."""

from __future__ import annotations

__all__ = ["check_device", "default_device", "device_problem", "device_syntax_problem"]


def default_device() -> str:
    """``cuda`` when this machine has a CUDA device, else ``cpu``."""
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"


def device_syntax_problem(device) -> str | None:
    """None when ``device`` names a torch device of a kind oscar runs on (cpu, cuda[:N], mps), else why not;
    whether this machine has it is :func:`device_problem`'s question."""
    import torch

    text = str(device)
    try:
        parsed = torch.device(device)
    except (RuntimeError, ValueError, TypeError):
        return f"expected a torch device such as cpu, cuda or cuda:1, found {text!r}"
    if parsed.type not in ("cpu", "cuda", "mps"):
        return f"expected cpu, cuda[:N] or mps, found {text!r}"
    return None


def device_problem(device) -> str | None:
    """None when ``device`` (a string or ``torch.device``) is a device this machine has, else why not.

    The reason reads "expected ..., found ...": cpu always; cuda[:N] when CUDA is available and N is below
    the device count; mps when the MPS backend is available; anything else is refused.
    """
    import torch

    text = str(device)
    syntax = device_syntax_problem(device)
    if syntax is not None:
        return syntax
    parsed = torch.device(device)
    if parsed.type == "cuda":
        if not torch.cuda.is_available():
            return (
                f"expected a device this machine has, found {text!r}: no CUDA device is available here "
                f"(torch {torch.__version__}, torch.cuda.is_available() is False)"
            )
        count = torch.cuda.device_count()
        if parsed.index is not None and parsed.index >= count:
            return (
                f"expected a device this machine has, found {text!r}: it has {count} CUDA device(s), "
                f"cuda:0 to cuda:{count - 1}"
            )
    elif parsed.type == "mps" and not torch.backends.mps.is_available():
        return f"expected a device this machine has, found {text!r}: MPS is not available here"
    return None


def check_device(device, error: type[Exception]) -> None:
    """Raise ``error("device: <why>")`` unless ``device`` is one this machine has (:func:`device_problem`)."""
    problem = device_problem(device)
    if problem is not None:
        raise error(f"device: {problem}")
