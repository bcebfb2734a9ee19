"""Simulators of the closed loop, found by name: plugins of ``run_closed_loop`` as embodiments are of the renderer.

A simulator is a factory ``(session, emb, camera, first, size, fps, chunk_frames) -> world`` whose world has
``first``, ``step`` and ``outcome`` (:func:`oscar_core.evaluation.closed_loop.run_closed_loop`'s ``simulator``);
an ``identity`` attribute (a string) names it in the run's fingerprint. A distribution registers one under the
entry point group :data:`GROUP`, e.g. in its ``pyproject.toml``::

    [project.entry-points."oscar.simulators"]
    toy = "oscar_core.toyworld.closed_loop:toy_simulator"

which is how the toy world registers its own, so that the closed loop (this floor) never imports the toy world
(the floor above). ``oscar eval closed-loop --simulator NAME`` runs the cells in it instead of a world model.
An editable checkout whose ``pyproject.toml`` gained an entry point sees it after ``pip install -e .`` again
(entry points are installed metadata); the error for an unknown name says so.
"""

from __future__ import annotations

import importlib.metadata as md
from collections.abc import Callable

from ..metrics.common import MetricInputError

__all__ = ["GROUP", "simulator_entry_points", "load_simulator"]

#: The entry point group simulators register under.
GROUP = "oscar.simulators"


def simulator_entry_points() -> dict[str, md.EntryPoint]:
    """``{name: entry point}`` of every installed simulator; a :class:`MetricInputError` when two distributions
    register one name differently (naming both)."""
    found: dict[str, md.EntryPoint] = {}
    for ep in md.entry_points(group=GROUP):
        old = found.get(ep.name)
        if old is not None and old.value != ep.value:  # the same distribution seen twice on sys.path is no clash
            raise MetricInputError(
                GROUP,
                ep.name,
                "one simulator per name",
                f"{old.value} ({_dist(old)}) and {ep.value} ({_dist(ep)})",
            )
        found[ep.name] = ep
    return found


def load_simulator(name: str, source: str = "--simulator") -> Callable:
    """The simulator factory registered as ``name``; a :class:`MetricInputError` naming ``source``, the installed
    names and the group when there is none, or when it does not import."""
    eps = simulator_entry_points()
    if name not in eps:
        names = ", ".join(sorted(eps)) or "none"
        raise MetricInputError(
            source,
            "value",
            f"an installed simulator (entry point group {GROUP}: {names}; an editable checkout needs "
            "`pip install -e .` again after its pyproject.toml gains one)",
            repr(name),
        )
    try:
        factory = eps[name].load()
    except (ImportError, AttributeError) as exc:
        raise MetricInputError(
            source, "value", f"an importable simulator ({eps[name].value})", f"{type(exc).__name__}: {exc}"
        ) from None
    if not callable(factory):
        raise MetricInputError(source, "value", "a simulator factory (a callable)", type(factory).__name__)
    return factory


def _dist(ep: md.EntryPoint) -> str:
    return f"{ep.dist.name} {ep.dist.version}" if ep.dist is not None else "<unknown distribution>"
