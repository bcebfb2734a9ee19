"""A Gymnasium environment over oscar's closed loop: one session of a closed-loop manifest is one episode.

:class:`ClosedLoopEnv` runs the loop of ``oscar eval closed-loop`` (docs/closed-loop.md) with the agent outside it:
``reset`` opens a session's world (the world model, or a simulator such as the toy world's) and returns the first
observation, exactly as a policy would be sent it; each ``step(action)`` executes **one** action row of the
declared action space at the policy's control rate (:class:`~oscar_core.evaluation.closed_loop_step.CellState`,
the state ``oscar eval closed-loop`` uses) and, as soon as the commanded path covers the world's next chunk, the
world generates it. The episode ends (``terminated``) when the session's ``horizon`` frames exist; then the judge
(if any) gives its verdict on the whole video and the reward is 1.0 for success, 0.0 otherwise (every earlier
reward is 0.0). ``truncated`` is never set by the environment itself (a ``TimeLimit`` wrapper may set it).

``info``: ``session``, ``frame`` (the index of the latest frame, the one observed), ``t_s`` (seconds of commanded
path), ``clipped`` (1 if this action was clipped to the joint limits or the gripper to [0, 1]) and
``clipped_total``, ``ik_position_error_m`` / ``ik_rotation_error_rad`` (the IK residual of an end-effector action,
NaN for joint spaces); at the end also ``verdict`` (``binary``, ``partial``, ``reason``, ``status``) and
``outcome`` (the world's own, e.g. the toy simulator's ground truth; empty for a world model).

A policy of the loop's protocol (``infer(obs) -> {"actions": (H, D)}``) driven by :func:`run_policy` gives the cell
``oscar eval closed-loop`` gives for the same session, seed and ``replan_every`` (tested on the toy simulator and
on ``oscar-toy``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping

import numpy as np

from .._util.optional import require
from ..errors import OscarError
from ..evaluation.closed_loop_cell import check_one_frame_context, open_world
from ..evaluation.closed_loop_manifest import ClosedLoopManifest, load_closed_loop_manifest
from ..evaluation.closed_loop_step import CellState
from ..policy.protocol import PolicySpec, check_answer
from ..policy.spaces import ActionAdapter
from .spaces import action_columns, action_space_of, check_action, extras_as_values, observation_space_of

gym = require("gymnasium", "gym")

__all__ = ["ClosedLoopEnv", "run_policy", "load_env_judge"]


def load_env_judge(judge):
    """A judge for the end of an episode: None, an object with ``judge_many``, a function ``(video, clip) ->
    {"binary", "partial", "reason"}``, or the ``module:attr`` / ``file.py:attr`` of either (as ``--judge``)."""
    from ..metrics.programmatic import ProgrammaticJudge

    if judge is None or hasattr(judge, "judge_many"):
        return judge
    name = None
    if isinstance(judge, str):
        from .._util.user_code import import_attr

        name, judge = judge, import_attr(judge, "judge")
        if hasattr(judge, "judge_many"):
            return judge
    if not callable(judge):
        raise OscarError(f"judge: expected a judge object, a function (video, clip) or module:attr, found {judge!r}")
    return ProgrammaticJudge(judge, name=name, version=str(getattr(judge, "version", "1")))


def _policy_spec(manifest: ClosedLoopManifest, policy) -> PolicySpec:
    if isinstance(policy, PolicySpec):
        return policy
    if isinstance(policy, Mapping):
        return PolicySpec.from_dict({"name": "agent", "policy": "<agent>", **policy}, source="policy")
    names = [p.name for p in manifest.policies]
    if policy is None:
        if not names:
            raise OscarError(f"{manifest.path}: policies: expected a declaration for the agent, found none")
        return manifest.policies[0]
    if policy not in names:
        raise OscarError(f"policy: expected one of the manifest's policies {names}, found {policy!r}")
    return manifest.policies[names.index(policy)]


class ClosedLoopEnv(gym.Env):
    """One closed-loop session per episode (module docstring).

    manifest: a closed-loop manifest (path or loaded); policy: the declaration the agent acts under (a policy
    name of the manifest, a :class:`~oscar_core.policy.protocol.PolicySpec`, a dict of its fields; None: the
    manifest's first) — its action space, control rate, image size, gripper mode and observation keys; its source
    is not loaded. The world: ``simulator`` (a factory as ``run_closed_loop`` takes; ``fps`` and ``chunk_frames``
    required), else the world model ``model`` (loaded) or ``model_spec`` (``oscar_zoo.load``, on the first
    reset), with ``sampler`` (None: the card's recommended settings) and ``chunk_frames`` (None: the card's).
    judge: see :func:`load_env_judge`. sessions: names of the sessions to draw from (None: all). render_mode:
    ``"rgb_array"`` or None.

    ``reset(seed=, options=)``: the session is ``options["session"]`` or drawn with the environment's generator;
    the world model's noise seed is ``options["noise_seed"]``, else the session's ``seed`` (as the command's).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        manifest,
        *,
        policy=None,
        model=None,
        model_spec: str | None = None,
        revision: str | None = None,
        simulator: Callable | None = None,
        fps: float | None = None,
        chunk_frames: int | None = None,
        sampler=None,
        judge=None,
        sessions=None,
        render_mode: str | None = None,
        device="cpu",
        dtype=None,
        plugin_paths=(),
    ):
        from ..plugin.registry import get_embodiment

        self.manifest = manifest if isinstance(manifest, ClosedLoopManifest) else load_closed_loop_manifest(manifest)
        where = str(self.manifest.path)
        chosen = list(self.manifest.sessions)
        if sessions is not None:
            by_name = {s.session: s for s in chosen}
            missing = [n for n in sessions if n not in by_name]
            if missing:
                raise OscarError(f"{where}: sessions: expected names of its sessions, found {missing}")
            chosen = [by_name[n] for n in sessions]
        if not chosen:
            raise OscarError(f"{where}: sessions: expected at least one, found none")
        bodies = sorted({s.embodiment for s in chosen})
        if len(bodies) != 1:
            raise OscarError(f"{where}: sessions: expected one embodiment per environment, found {bodies}")
        if simulator is None and model is None and model_spec is None:
            raise OscarError("ClosedLoopEnv: expected a world (model, model_spec or simulator), found none")
        if simulator is not None and (fps is None or chunk_frames is None):
            raise OscarError(f"ClosedLoopEnv: simulator: expected fps and chunk_frames, found {fps}/{chunk_frames}")
        if render_mode not in (None, "rgb_array"):
            raise OscarError(f"render_mode: expected 'rgb_array' or None, found {render_mode!r}")
        if simulator is None and model is not None:
            check_one_frame_context(getattr(model, "card", None))
        self.sessions = chosen
        self.emb = get_embodiment(bodies[0], plugin_paths)
        self.policy_spec = _policy_spec(self.manifest, policy)
        self.render_mode = render_mode
        self.judge = load_env_judge(judge)
        self._model, self._model_spec, self._revision, self._device, self._dtype = (
            model,
            model_spec,
            revision,
            device,
            dtype,
        )
        self._simulator, self._fps, self._chunk_frames, self._sampler = simulator, fps, chunk_frames, sampler
        self.observation_space = observation_space_of(self.policy_spec, self.emb, chosen, where)
        adapter = ActionAdapter(
            self.emb, self.policy_spec.action_space, self.policy_spec.gripper, self.policy_spec.control_hz
        )
        self.action_space = action_space_of(adapter)
        self.columns = action_columns(self.policy_spec.action_space, self.emb)
        self.metadata = {**self.metadata, "render_fps": float(fps or 10.0)}  # the world's, from the first reset on
        self.session = None
        self.world = None
        self.state: CellState | None = None
        self._extras: dict = {}
        self.on_close: list[Callable[[], None]] = []  # run by close(), e.g. removing a temporary session folder

    # ------------------------------------------------------------------ the world
    def get_model(self):
        """The world model, loaded on first use (``model_spec``)."""
        if self._model is None:
            import oscar_zoo

            model = oscar_zoo.load(self._model_spec, self._revision, device=self._device, dtype=self._dtype)
            check_one_frame_context(model.card)
            self._model = model
        return self._model

    def _sampler_config(self):
        if self._sampler is None and self._simulator is None:
            from ..model.card_sampler import resolve_sampler

            self._sampler = resolve_sampler(getattr(self.get_model().card, "sampler", None)).config
        return self._sampler

    # ------------------------------------------------------------------ gymnasium
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        name = options.pop("session", None)
        noise = options.pop("noise_seed", None)
        if options:
            raise OscarError(f"reset: options: expected 'session' and/or 'noise_seed', found {sorted(options)}")
        if name is None:
            s = self.sessions[int(self.np_random.integers(len(self.sessions)))]
        else:
            names = [x.session for x in self.sessions]
            if name not in names:
                raise OscarError(f"reset: options['session']: expected one of {names}, found {name!r}")
            s = self.sessions[names.index(name)]
        if noise is not None:
            s = dataclasses.replace(s, seed=int(noise))
        world, q0, g0 = open_world(
            s,
            self.emb,
            get_model=self.get_model,
            simulator=self._simulator,
            sampler=self._sampler_config(),
            size=self.manifest.size,
            chunk_frames=self._chunk_frames,
            fps=self._fps,
        )
        joints = self.observation_space[self.policy_spec.keys["joint_position"]]
        lo, hi = joints.low, joints.high
        if np.any(q0 < lo) or np.any(q0 > hi):
            j = int(np.argmax((q0 < lo) | (q0 > hi)))
            raise OscarError(
                f"{s.initial_state}: q[0, {j}] ({self.emb.joint_names[j]}): expected within the joint limits "
                f"[{lo[j]:.4g}, {hi[j]:.4g}], found {q0[j]:.6g}"
            )
        self.session, self.world = s, world
        self.state = CellState(
            world.first, world.fps, world.chunk, self.policy_spec, self.emb, q0=q0, g0=g0, horizon=s.horizon
        )
        self._extras = extras_as_values(s.extras, self.observation_space)
        self.metadata = {**self.metadata, "render_fps": float(world.fps)}
        return self._observation(), {"session": s.session, "frame": 0}

    def step(self, action):
        info = self.act(action)
        while (request := self.chunk_request()) is not None:  # every chunk the path now covers
            self.state.accept(*request, self.world.step(*request))
        return self.finish(info)

    def render(self):
        if self.render_mode != "rgb_array" or self.state is None:
            return None
        return self.state.frames[-1].copy()

    def close(self):
        self.world = None
        self.state = None
        while self.on_close:
            self.on_close.pop()()

    # ------------------------------------------------------------------ the three parts of a step
    def act(self, action) -> dict:
        """Check ``action`` and append it to the commanded path (no frames generated); returns the step's info."""
        if self.state is None:
            raise gym.error.ResetNeeded("step: expected reset() first (no episode is open)")
        if self.state.finished:
            raise gym.error.ResetNeeded("step: the episode ended (terminated); call reset()")
        a = check_action(action, self.action_space, self.columns, self.policy_spec.action_space)
        res = self.state.execute(a[None])
        return {
            "session": self.session.session,
            "clipped": int(res.clipped),
            "ik_position_error_m": float(res.ik_position_error[0]),
            "ik_rotation_error_rad": float(res.ik_rotation_error[0]),
        }

    def chunk_request(self):
        """``(q (n, J), gripper (n, G))`` of the chunk the world owes now, or None (path short of it, or done)."""
        st = self.state
        return st.chunk_request() if st is not None and st.covered and not st.finished else None

    def finish(self, info: dict):
        """The step's ``(observation, reward, terminated, truncated, info)`` once every owed chunk exists."""
        st = self.state
        info = {**info, "frame": st.frame_index, "t_s": float(st.times[-1]), "clipped_total": int(st.clipped)}
        reward = 0.0
        if st.finished:
            verdict = self._verdict()
            if verdict is not None:
                reward = float(verdict["binary"] == 1)
                info["verdict"] = verdict
            info["outcome"] = self.world.outcome() or {}
        return self._observation(), reward, st.finished, False, info

    # ------------------------------------------------------------------ helpers
    def _observation(self) -> dict:
        obs, _ = self.state.observe(self.session.task, self._extras)
        return {k: v.copy() if isinstance(v, np.ndarray) else v for k, v in obs.items()}  # new arrays per call

    def frames(self) -> np.ndarray:
        """(T, H, W, 3) uint8 the episode's frames so far."""
        return self.state.paths()[0]

    def joint_path(self) -> tuple[np.ndarray, np.ndarray]:
        """(T, J) joint positions and (T, G) gripper signals of the episode's frames so far."""
        _, q, g = self.state.paths()
        return q, g

    def _verdict(self) -> dict | None:
        if self.judge is None:
            return None
        from ..metrics.judge_records import JudgeClip

        s = self.session
        clip = JudgeClip(
            name=f"{s.session}/{self.policy_spec.name}",
            video=self.frames(),
            instruction=s.task,
            policy=self.policy_spec.name,
            session=s.session,
            info=s.info,
        )
        (v,) = self.judge.judge_many([clip])
        return {"binary": v.binary, "partial": v.partial, "reason": v.reason, "status": v.status}


def run_policy(env: ClosedLoopEnv, policy, *, replan_every: int | None = None, seed=None, options=None) -> dict:
    """Run one episode of ``env`` with a policy of the loop's protocol (``infer(obs) -> {"actions": (H, D)}``,
    optional ``reset()``): every ``replan_every`` steps (default the declaration's ``actions_per_call``) the
    policy is called on the latest observation and its first rows are stepped one by one, as ``oscar eval
    closed-loop`` executes them. Returns ``frames`` (T, H, W, 3), ``q`` (T, J), ``gripper`` (T, G), ``reward``,
    ``info`` (the last step's) and ``calls``. A bad answer raises :class:`~oscar_core.policy.protocol.PolicyFault`;
    an answer's ``"done": true`` is ignored (the episode ends at the horizon only)."""
    K = int(replan_every or env.policy_spec.actions_per_call)
    obs, info = env.reset(seed=seed, options=options)
    if hasattr(policy, "reset"):
        policy.reset()
    calls, reward, done = 0, 0.0, False
    while not done:
        answer = policy.infer(obs)
        actions = check_answer(answer, width=env.action_space.shape[0], min_horizon=K, bounds=None)
        calls += 1
        for row in actions[:K]:
            obs, reward, done, _, info = env.step(row)
            if done:
                break
    q, g = env.joint_path()
    return {"frames": env.frames(), "q": q, "gripper": g, "reward": reward, "info": info, "calls": calls}
