"""argparse ``type=`` functions that refuse what a bare ``int``/``float`` lets through.

``type=float`` accepts ``nan``, ``inf`` and negatives, ``type=int`` accepts 0
and negatives; the option then fails late or, worse, silently does something
else (``--guidance nan``: a black video). These check the range too, so a bad
option is refused by the parser, before any work, as ``argument --X: …``.
"""

from __future__ import annotations

import argparse
import math

from .devices import default_device  # re-exported: the model-running commands' default (imports torch only when called)

__all__ = ["count", "default_device", "device", "device_name", "interval", "number"]


def count(minimum: int = 1):
    """An integer ≥ ``minimum`` (``count(0)``: 0 allowed; ``count(None)``: any integer)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, found {text!r}") from None
        if minimum is not None and value < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, found {value}")
        return value

    parse.__name__ = "integer"  # argparse names the type in its own messages
    return parse


def number(minimum: float | None = None, maximum: float | None = None, *, above: float | None = None):
    """A finite number in [``minimum``, ``maximum``] (and > ``above`` when given)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, found {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected a finite number, found {text!r}")
        if above is not None and not value > above:
            raise argparse.ArgumentTypeError(f"expected a number > {above:g}, found {value:g}")
        if minimum is not None and value < minimum:
            raise argparse.ArgumentTypeError(f"expected a number >= {minimum:g}, found {value:g}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"expected a number <= {maximum:g}, found {value:g}")
        return value

    parse.__name__ = "number"
    return parse


def interval(text: str) -> tuple[float, float]:
    """``LO,HI`` → (lo, hi): two finite numbers with 0 <= LO <= HI <= 1 (a range of noise levels)."""
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        lo, hi = float(parts[0]), float(parts[1])
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LO,HI (two numbers), found {text!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo <= hi <= 1.0):
        raise argparse.ArgumentTypeError(f"expected 0 <= LO <= HI <= 1, found {text!r}")
    return lo, hi


def _device_check(check: str):
    """An argparse type returning a device name as given once ``oscar_core._util.devices.<check>`` finds no problem.

    "cpu" passes without importing torch: argparse also converts string defaults, and a render needs no torch.
    """

    def parse(text: str) -> str:
        if text == "cpu":
            return text
        from . import devices as _devices

        problem = getattr(_devices, check)(text)
        if problem is not None:
            raise argparse.ArgumentTypeError(problem)
        return text

    parse.__name__ = "device"  # argparse names the type in its own messages
    return parse


#: A torch device this machine has (``cpu``, ``cuda``, ``cuda:1``, ``mps``), returned as given. ``--device cuda`` on
#: a machine without CUDA otherwise fails deep inside loading the weights (a traceback from safetensors or torch)
#: after the output folder exists; this refuses it at the parser. torch is imported only when the option is given.
device = _device_check("device_problem")

#: A well-formed torch device name, not checked against this machine: for devices that may live elsewhere
#: (``oscar eval run --engine ray``'s workers on other machines).
device_name = _device_check("device_syntax_problem")
