"""Gymnasium environments over oscar's closed loop (``pip install "oscar-wm[gym]"``).

* :mod:`oscar_core.envs.closed_loop_env` — :class:`ClosedLoopEnv`: one session of a closed-loop manifest per
  episode, the world model or a simulator behind it; :func:`run_policy` drives it with a policy of the loop's
  protocol;
* :mod:`oscar_core.envs.vector` — :class:`ClosedLoopVectorEnv`: N episodes, one batched world-model call per chunk;
* :mod:`oscar_core.envs.spaces` — the observation and action spaces, and the action check;
* :mod:`oscar_core.envs.toy` — the toy world's registered ids (``oscar/ToySim-v0``, ``oscar/ToyWorldModel-v0``),
  registered when gymnasium is imported after (or before) ``import oscar_core``.

Names are re-exported flat; submodules load on first use. See docs/closed-loop.md.
"""

from __future__ import annotations

from .._util.lazy import lazy_exports

_EXPORTS = {
    "ClosedLoopEnv": "closed_loop_env",
    "run_policy": "closed_loop_env",
    "ClosedLoopVectorEnv": "vector",
    "ActionSpaceError": "spaces",
    "make_toy_env": "toy",
    "make_toy_vector_env": "toy",
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
