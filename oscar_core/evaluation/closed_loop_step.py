"""The closed loop's state, one step at a time: what a policy is shown, how its actions extend the commanded path,
and when the world owes the next chunk.

:class:`CellState` holds one cell's episode between the world and whoever acts: the frames so far, the commanded
path (knots at the policy's control rate: times, joint positions, gripper closure) and the per-frame joint path.
Two drivers use it and nothing else:

* :func:`~.closed_loop_cell.cell_steps` (``oscar eval closed-loop``, the lock-step batches, Ray): calls the policy
  while the path does not cover the next chunk, then asks the world for the chunk;
* :class:`oscar_core.envs.ClosedLoopEnv` (Gymnasium): one action per ``step``, the chunk generated as soon as the
  path covers it.

Both end at the same cells for the same actions: a chunk's joint positions are read off the knots at the world's
frame times (:func:`~oscar_core.policy.spaces.resample`), which depends only on the knots up to the chunk's end.
"""

from __future__ import annotations

import hashlib

import numpy as np

from ..policy.protocol import PolicySpec
from ..policy.spaces import ActionAdapter, AdapterResult, resample

__all__ = ["CellState", "observation", "closure_to_signal", "signal_to_closure"]


def observation(
    spec: PolicySpec, frame: np.ndarray, q: np.ndarray, closure: float, task: str, extras: dict
) -> tuple[dict, str]:
    """The observation dict under the policy's keys (docs/closed-loop.md, "observe"), and the SHA-256 of the image
    sent. frame: (H, W, 3) uint8, resized to ``spec.image_size`` (width, height) with area interpolation; q: (J,)
    joint positions; closure: the gripper closure in [0, 1]."""
    import cv2

    w, h = spec.image_size
    image = frame if frame.shape[:2] == (h, w) else cv2.resize(frame, (w, h), interpolation=cv2.INTER_AREA)
    image = np.ascontiguousarray(image, dtype=np.uint8)
    obs = dict(extras)
    keys = spec.keys
    obs[keys["image"]] = image
    obs[keys["wrist_image"]] = np.zeros_like(image)
    obs[keys["joint_position"]] = np.asarray(q, dtype=np.float64).copy()
    obs[keys["gripper_position"]] = np.array([closure], dtype=np.float64)
    obs[keys["prompt"]] = task
    return obs, hashlib.sha256(image.tobytes()).hexdigest()


def closure_to_signal(emb, closure: np.ndarray) -> np.ndarray:
    """(n,) closure → (n, G) raw gripper signals (every gripper follows the one command)."""
    from ..kinematics.workspace import openness_to_signal

    openness = np.repeat((1.0 - np.asarray(closure, float))[:, None], len(emb.grippers), axis=1)
    return openness_to_signal(emb, openness)


def signal_to_closure(emb, signal: np.ndarray) -> float:
    """(G,) raw gripper signals → the first gripper's closure in [0, 1] (0 for a robot without grippers)."""
    if not len(emb.grippers):
        return 0.0
    return float(1.0 - emb.gripper_openness(np.asarray(signal, float)[None, :])[0, 0])


class CellState:
    """One cell's episode in progress (module docstring).

    first: (H, W, 3) uint8 the world's first frame; fps: the world's frame rate; chunk: new frames per world step;
    spec: the policy's declaration (its action space, gripper mode and control rate build the
    :class:`~oscar_core.policy.spaces.ActionAdapter`); emb: the embodiment; q0 (J,), g0 (G,): the robot's first
    joint positions and raw gripper signals; horizon: frames in the episode, the first included.

    ``frames`` (list of (H, W, 3) uint8), ``q_frames`` / ``g_frames`` (per frame, (J,) / (G,)), and the knots
    ``times`` (s), ``knots_q`` ((J,) each), ``knots_c`` (closures) grow as the episode goes; ``clipped`` counts
    clipped actions.
    """

    def __init__(self, first, fps: float, chunk: int, spec: PolicySpec, emb, *, q0, g0, horizon: int):
        self.spec, self.emb = spec, emb
        self.adapter = ActionAdapter(emb, spec.action_space, spec.gripper, spec.control_hz)
        self.fps, self.chunk, self.horizon = float(fps), int(chunk), int(horizon)
        self.frames = [first]
        self.q_frames = [np.asarray(q0, float)]
        self.g_frames = [np.asarray(g0, float)]
        self.times, self.knots_q = [0.0], [np.asarray(q0, float)]
        self.knots_c = [signal_to_closure(emb, g0)]
        self.clipped = 0
        # knot n after the last hold is at hold_t + n / control_hz: the same float whether actions come one or K
        # at a time (a running sum t + 1/hz would drift in the last bits)
        self._hold_t, self._since_hold = 0.0, 0

    @property
    def finished(self) -> bool:
        """``horizon`` frames exist."""
        return len(self.frames) >= self.horizon

    @property
    def frame_index(self) -> int:
        """Index of the latest frame (the one a policy is shown)."""
        return len(self.frames) - 1

    @property
    def chunk_end(self) -> float:
        """Time (s) of the next chunk's last frame."""
        return (len(self.frames) - 1 + self.chunk) / self.fps

    @property
    def covered(self) -> bool:
        """The commanded path reaches the next chunk's last frame (the world can generate it)."""
        return self.times[-1] >= self.chunk_end - 1e-9

    def observe(self, task: str, extras: dict) -> tuple[dict, str]:
        """:func:`observation` of the latest frame and the end of the commanded path."""
        return observation(self.spec, self.frames[-1], self.knots_q[-1], self.knots_c[-1], task, extras)

    def execute(self, actions) -> AdapterResult:
        """Append ``actions`` (K, D) of the declared space, executed from the end of the path at the control
        rate, to the commanded path; returns what the adapter did (joint positions, clips, IK residuals)."""
        res = self.adapter.apply(actions, self.knots_q[-1])
        n0, hz = self._since_hold, self.spec.control_hz
        self.times += [self._hold_t + (n0 + i + 1) / hz for i in range(len(res.q))]
        self._since_hold += len(res.q)
        self.knots_q += list(res.q)
        self.knots_c += list(res.closure)
        self.clipped += res.clipped
        return res

    def hold(self) -> None:
        """Hold the last pose to the next chunk's end (a policy that said ``done`` mid-chunk)."""
        if not self.covered:
            self.times.append(self.chunk_end)
            self._hold_t, self._since_hold = self.chunk_end, 0
            self.knots_q.append(self.knots_q[-1])
            self.knots_c.append(self.knots_c[-1])

    def chunk_request(self) -> tuple[np.ndarray, np.ndarray]:
        """(chunk, J) joint positions and (chunk, G) gripper signals of the next chunk's frames, read off the
        commanded path at the world's frame times (requires :attr:`covered`)."""
        at = (len(self.frames) + np.arange(self.chunk)) / self.fps
        qs, cs = resample(np.array(self.times), np.array(self.knots_q), np.array(self.knots_c), at)
        return qs, closure_to_signal(self.emb, cs)

    def accept(self, q: np.ndarray, gripper: np.ndarray, new: np.ndarray) -> None:
        """Take the world's (chunk, H, W, 3) uint8 frames generated for the request ``(q, gripper)``."""
        self.frames += list(new)
        self.q_frames += list(q)
        self.g_frames += list(gripper)

    def paths(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(T, H, W, 3) uint8 frames, (T, J) joint positions and (T, G) gripper signals, T = min(frames,
        horizon)."""
        T = min(len(self.frames), self.horizon)
        return np.stack(self.frames[:T]), np.stack(self.q_frames[:T]), np.stack(self.g_frames[:T])
