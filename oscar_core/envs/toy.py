"""The toy world as registered Gymnasium environments (on the CPU, no download).

``gymnasium.make("oscar/ToySim-v0")`` is the toy world's simulator (:class:`~oscar_core.toyworld.closed_loop.
ToySimulator`: frames rendered from the true state, its ground truth in ``info["outcome"]`` at the end);
``gymnasium.make("oscar/ToyWorldModel-v0")`` is the world model ``oscar-toy`` over the same sessions. Both write
toy sessions as ``oscar toyworld closed-loop-sessions`` does (into ``folder``, else a temporary folder removed by
``close()``), declare the toy policies' action space (``ee_position`` at 10 Hz, 64 × 64 images) and judge the
episode with :func:`oscar_core.toyworld.judge.ball_moved` (the reward: 1.0 when the ball was moved).
``gymnasium.make_vec(id, num_envs=N)`` gives a :class:`~oscar_core.envs.vector.ClosedLoopVectorEnv` (one batched
world-model call per chunk for the N episodes).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

__all__ = ["make_toy_env", "make_toy_vector_env", "TOY_JUDGE"]

TOY_JUDGE = "oscar_core.toyworld.judge:ball_moved"


def _toy_kwargs(
    world: str,
    embodiment: str,
    sessions: int,
    session_seed: int,
    horizon: int,
    policy: str,
    folder,
    model_spec: str,
    chunk_frames: int,
    kwargs: dict,
):
    from ..toyworld.closed_loop import toy_simulator, write_closed_loop_sessions

    if world not in ("simulator", "model"):
        raise ValueError(f"world: expected 'simulator' or 'model', found {world!r}")
    temp = None
    if folder is None:
        temp = tempfile.TemporaryDirectory(prefix="oscar-toy-env-")
        folder = temp.name
    names = [policy] if isinstance(policy, str) else None  # a declaration of its own: the toy policies listed
    manifest = write_closed_loop_sessions(
        Path(folder), [embodiment], sessions, seed=session_seed, horizon=horizon, policies=names
    )
    kwargs = {"policy": policy, "judge": TOY_JUDGE, "chunk_frames": chunk_frames, **kwargs}
    if world == "simulator":
        kwargs.update(simulator=toy_simulator, fps=10.0)
    elif "model" not in kwargs:
        kwargs.setdefault("model_spec", model_spec)
    return manifest, kwargs, temp


def make_toy_env(
    *,
    world: str = "simulator",
    embodiment: str = "toyarm",
    sessions: int = 4,
    session_seed: int = 0,
    horizon: int = 49,
    policy: str = "exact",
    folder=None,
    model_spec: str = "oscar-toy",
    chunk_frames: int = 17,
    **kwargs,
):
    """A :class:`~oscar_core.envs.ClosedLoopEnv` on ``sessions`` toy sessions of ``embodiment`` (seed
    ``session_seed``, ``horizon`` frames at 10 fps); world ``"simulator"`` or ``"model"`` (``model_spec``);
    ``policy``: the toy policy whose declaration the agent acts under, or a declaration of its own (a dict of
    :class:`~oscar_core.policy.protocol.PolicySpec` fields); ``kwargs``: more of ClosedLoopEnv's."""
    from .closed_loop_env import ClosedLoopEnv

    manifest, kw, temp = _toy_kwargs(
        world, embodiment, sessions, session_seed, horizon, policy, folder, model_spec, chunk_frames, kwargs
    )
    env = ClosedLoopEnv(manifest, **kw)
    if temp is not None:
        env.on_close.append(temp.cleanup)
    return env


def make_toy_vector_env(
    num_envs: int = 1,
    *,
    world: str = "simulator",
    embodiment: str = "toyarm",
    sessions: int = 4,
    session_seed: int = 0,
    horizon: int = 49,
    policy: str = "exact",
    folder=None,
    model_spec: str = "oscar-toy",
    chunk_frames: int = 17,
    **kwargs,
):
    """``num_envs`` toy episodes in lock-step (:class:`~oscar_core.envs.vector.ClosedLoopVectorEnv`); the
    arguments of :func:`make_toy_env`."""
    from .vector import ClosedLoopVectorEnv

    manifest, kw, temp = _toy_kwargs(
        world, embodiment, sessions, session_seed, horizon, policy, folder, model_spec, chunk_frames, kwargs
    )
    env = ClosedLoopVectorEnv(num_envs, manifest, **kw)
    if temp is not None:
        env.on_close.append(temp.cleanup)
    return env
