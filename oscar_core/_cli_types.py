"""argparse ``type=`` functions that refuse what a bare ``int``/``float`` lets through.

``type=float`` accepts ``nan``, ``inf`` and negatives, ``type=int`` accepts 0
and negatives; the option then fails late or, worse, silently does something
else (``--guidance nan``: a black video). These check the range too, so a bad
option is refused by the parser, before any work, as ``argument --X: …``.
"""

from __future__ import annotations

import argparse
import math

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


def device(text: str) -> str:
    """A torch device this machine has (``cpu``, ``cuda``, ``cuda:1``, ``mps``), returned as given.

    ``--device cuda`` on a machine without CUDA otherwise fails deep inside loading the weights (a traceback
    from safetensors or torch) after the output folder exists; this refuses it at the parser. torch is
    imported only when the option is given.
    """
    if text == "cpu":  # argparse also converts string defaults: "cpu" must not import torch (a render needs none)
        return text
    from ._devices import device_problem

    problem = device_problem(text)
    if problem is not None:
        raise argparse.ArgumentTypeError(problem)
    return text


device.__name__ = "device"


def device_name(text: str) -> str:
    """A well-formed torch device name (``cpu``, ``cuda``, ``cuda:1``, ``mps``), not checked against this machine:
    for devices that may live elsewhere (``oscar eval run --engine ray``'s workers on other machines)."""
    if text == "cpu":
        return text
    from ._devices import device_syntax_problem

    problem = device_syntax_problem(text)
    if problem is not None:
        raise argparse.ArgumentTypeError(problem)
    return text


device_name.__name__ = "device"


def default_device() -> str:
    """``cuda`` when this machine has a CUDA device, else ``cpu`` (the default of the model-running commands)."""
    from ._devices import default_device as default

    return default()
