"""N closed-loop episodes in lock-step, their chunks generated together: one batched world-model call per chunk.

:class:`ClosedLoopVectorEnv` is a Gymnasium ``VectorEnv`` of N :class:`~oscar_core.envs.ClosedLoopEnv` that share
one world model. Each ``step(actions)`` appends every episode's action to its commanded path, then generates the
chunks owed by all episodes at once with ``oscar eval closed-loop --batch-cells``'s machinery
(:func:`~oscar_core.evaluation.closed_loop_batch.generate_together`: one ``rollout_batch`` per group of equal
shapes, each episode with its own noise seed per chunk, so each episode's frames equal its single environment's up
to the batch's float rounding; a simulator's episodes step one by one). Autoreset is Gymnasium's default
(next step): the step after an episode ends resets that sub-environment and ignores its action.
"""

from __future__ import annotations

import numpy as np

from .._util.optional import require
from ..evaluation.closed_loop_batch import generate_together
from .closed_loop_env import ClosedLoopEnv

gym = require("gymnasium", "gym")

__all__ = ["ClosedLoopVectorEnv"]


class ClosedLoopVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` :class:`ClosedLoopEnv` over ``manifest`` (keyword arguments: those of ClosedLoopEnv; a
    ``model_spec`` is loaded once and shared). ``world_model_calls`` counts the batched calls made."""

    metadata = {"render_modes": ["rgb_array"], "autoreset_mode": gym.vector.AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int, manifest, **env_kwargs):
        from gymnasium.vector.utils import batch_space

        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs: expected an integer >= 1, found {num_envs!r}")
        self.envs = [ClosedLoopEnv(manifest, **env_kwargs) for _ in range(num_envs)]
        for env in self.envs[1:]:
            env.get_model = self.envs[0].get_model  # one world model for every episode
        self.num_envs = num_envs
        self.single_observation_space = self.envs[0].observation_space
        self.single_action_space = self.envs[0].action_space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.render_mode = self.envs[0].render_mode
        self.metadata = {**self.metadata, "render_fps": self.envs[0].metadata["render_fps"]}
        self._autoreset = np.zeros(num_envs, dtype=bool)
        self.world_model_calls = 0
        self.on_close: list = []

    def _batch(self, observations: list):
        from gymnasium.vector.utils import concatenate, create_empty_array

        out = create_empty_array(self.single_observation_space, self.num_envs)
        return concatenate(self.single_observation_space, observations, out)

    def reset(self, *, seed=None, options=None):
        if seed is None or isinstance(seed, int):
            seeds = [None if seed is None else seed + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
        observations, infos = [], {}
        for i, (env, s) in enumerate(zip(self.envs, seeds)):
            obs, info = env.reset(seed=s, options=options)
            observations.append(obs)
            infos = self._add_info(infos, info, i)
        self._autoreset[:] = False
        return self._batch(observations), infos

    def step(self, actions):
        actions = np.asarray(actions)
        results: list = [None] * self.num_envs
        acting = []
        for i, env in enumerate(self.envs):
            if self._autoreset[i]:
                obs, info = env.reset()
                results[i] = (obs, 0.0, False, False, info)
            else:
                acting.append((i, env.act(actions[i])))
        while True:
            owed = [(env, env.chunk_request()) for env in (self.envs[i] for i, _ in acting)]
            owed = [(env, req) for env, req in owed if req is not None]
            if not owed:
                break
            self.world_model_calls += 1
            for (env, req), frames in zip(owed, generate_together([(env.world, req) for env, req in owed])):
                env.state.accept(*req, frames)
        for i, info in acting:
            results[i] = self.envs[i].finish(info)
        infos: dict = {}
        for i, r in enumerate(results):
            infos = self._add_info(infos, r[4], i)
        rewards = np.array([r[1] for r in results], dtype=np.float64)
        terminated = np.array([r[2] for r in results], dtype=bool)
        truncated = np.array([r[3] for r in results], dtype=bool)
        self._autoreset = terminated | truncated
        return self._batch([r[0] for r in results]), rewards, terminated, truncated, infos

    def render(self):
        return tuple(env.render() for env in self.envs)

    def close_extras(self, **kwargs):
        for env in self.envs:
            env.close()
        while self.on_close:
            self.on_close.pop()()
