"""Toy pick-and-place policies that act only on the pixels and joint state they are sent, of graded skill.

Each speaks the policy protocol (``infer(obs) -> {"actions": (16, 4)}``, ``reset()``) in the ``ee_position``
action space (end-effector x, y, z in metres in the robot's base frame, then the gripper closure; 1 = closed)
at :data:`CONTROL_HZ`, executed :data:`EXECUTED` actions per call (:data:`SPEC`, the declaration a closed-loop
manifest gives them). What a policy reads: the camera image (DROID's ``observation/exterior_image_1_left``),
the joint positions (``observation/joint_position``), the prompt (the place position, ``... at x=0.123
y=-0.456``, metres) and the session's static extras ``toy/embodiment``, ``toy/intrinsics`` (fx, fy, cx, cy) and
``toy/world_to_cv`` (4x4): the robot it drives and how its camera is calibrated, nothing about the ball.

Perception: the ball's pixels by their reserved colour (:func:`~oscar_core.toyworld.locate.color_mask`), the
largest 8-connected blob's centroid, cast onto the plane of a resting ball's centre (z = R, R = 0.09 × the
robot's reach as the toy world sizes it, the reach estimated once per robot from 768 configurations of a fixed
seed). The ball is looked for on every call until the gripper starts to close; where it is not found, the last
estimate stands (none yet: the arm holds still).

Plan, in steps of 1/CONTROL_HZ from the first call (end-effector waypoints joined by minimum-jerk segments, the
segment under way restarting from the end-effector's current position, from the joint state by forward
kinematics): reach the grasp point 2R above the floor over the ball by step 14, close at step 16, lift to
2R + 0.25 reach by step 26, carry above the place point by 35, lower by 40, open at 41, lift by 48, hold.

Graded skill (:data:`POLICIES`): ``exact``; ``noisy`` (the perceived ball moved by an error drawn per episode,
N(0, (1.5 R)²) per horizontal axis); ``late`` (closes 1–6 steps late, drawn per episode, mostly after the
lift has started); ``never_closes``; ``random`` (random reachable waypoints and gripper). Two more look at the
ball on every call, so what they do depends on the frames the world shows them after the grasp: ``retry`` (aims
as ``noisy``, checks once the lift is done whether the ball came along and, if it still lies where it was, opens
and tries again once, from a new aim) and ``retry_far`` (the same with twice the aiming error); they need
sessions long enough for a second attempt (97 frames: ``--horizon 97``). Per-episode draws come from a generator
seeded by the first image's bytes, so a run is repeatable.
"""

from __future__ import annotations

import hashlib
import re

import numpy as np

__all__ = [
    "CONTROL_HZ",
    "EXECUTED",
    "HORIZON",
    "SPEC",
    "POLICIES",
    "ToyPickPlace",
    "ExactPolicy",
    "NoisyPolicy",
    "LatePolicy",
    "NeverClosesPolicy",
    "RandomPolicy",
    "RetryPolicy",
    "RetryFarPolicy",
    "CLASSIC",
    "policy_specs",
    "perceive_ball",
]

CONTROL_HZ = 10.0
EXECUTED = 8
HORIZON = 16
#: The declaration every toy policy needs in a closed-loop manifest (besides its name and source).
SPEC = {
    "action_space": "ee_position",
    "control_hz": CONTROL_HZ,
    "image_size": [64, 64],
    "actions_per_call": EXECUTED,
    "gripper": "position",
}
_PLACE = re.compile(r"x=(-?\d+(?:\.\d+)?)\s+y=(-?\d+(?:\.\d+)?)")
_REACH: dict[str, float] = {}


def _reach(emb) -> float:
    if emb.name not in _REACH:
        from ..kinematics.workspace import joint_limits, open_fk, reach_of

        lo, hi = joint_limits(emb)
        q = lo + np.random.default_rng(0).uniform(0, 1, (768, len(lo))) * (hi - lo)
        pts, ee = open_fk(emb, q)
        _REACH[emb.name] = reach_of(pts, ee)
    return _REACH[emb.name]


def perceive_ball(image: np.ndarray, intrinsics, world_to_cv, height: float) -> np.ndarray | None:
    """(3,) the ball's centre in metres, from its largest blob in ``image`` (H, W, 3) uint8 cast onto the plane
    z = ``height``; None when no ball pixels are seen."""
    import cv2

    from .locate import OBJECT_TARGET, color_mask

    mask = color_mask(image, OBJECT_TARGET).astype(np.uint8)
    n, _, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n < 2:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    u, v = cents[k]
    fx, fy, cx, cy = intrinsics
    T_wc = np.linalg.inv(np.asarray(world_to_cv, float))
    d = T_wc[:3, :3] @ np.array([(u - cx) / fx, (v - cy) / fy, 1.0])
    o = T_wc[:3, 3]
    if abs(d[2]) < 1e-9:
        return None
    s = (height - o[2]) / d[2]
    return o + s * d if s > 0 else None


def _min_jerk(a: np.ndarray, b: np.ndarray, s: float) -> np.ndarray:
    s = min(max(s, 0.0), 1.0)
    return a + (10 * s**3 - 15 * s**4 + 6 * s**5) * (b - a)


class ToyPickPlace:
    """The exact toy policy (module docstring); subclasses change one skill."""

    aim_sigma_radii = 0.0
    close_delay = (0, 0)  # steps, drawn per episode in [lo, hi]
    closes = True

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        self.step = 0
        self.t0 = 0  # the step the current attempt started at (a retrying policy starts again later)
        self.ball = None
        self.rng = None
        self.aim = np.zeros(2)
        self.delay = 0

    def _setup(self, obs: dict) -> None:
        from ..plugin.registry import get_embodiment
        from ..policy.ik import EndEffectorIK

        self.emb = get_embodiment(obs["toy/embodiment"])
        self.ik = EndEffectorIK(self.emb)
        self.scale = _reach(self.emb)
        self.R = 0.09 * self.scale
        image = np.asarray(obs["observation/exterior_image_1_left"])
        seed = int.from_bytes(hashlib.sha256(image.tobytes()).digest()[:8], "little")
        self.rng = np.random.default_rng(seed)
        self.aim = self.rng.normal(0.0, self.aim_sigma_radii, 2) * self.R
        self.delay = int(self.rng.integers(self.close_delay[0], self.close_delay[1] + 1))

    def infer(self, obs: dict) -> dict:
        if self.rng is None:
            self._setup(obs)
        q = np.asarray(obs["observation/joint_position"], float)
        ee = self.ik.pose(q)[:3, 3]
        close_at = 16 + self.delay
        if self.step - self.t0 < close_at - 2:  # look for the ball until the gripper is about to close
            seen = self._look(obs)
            if seen is not None:
                self.ball = seen
        else:
            self._after_grasp(obs)
        m = _PLACE.search(str(obs.get("prompt", "")))
        if self.ball is None or m is None:  # nothing to aim at: hold still, gripper open
            acts = np.tile(np.append(ee, 0.0), (HORIZON, 1))
        else:
            acts = self._plan(ee, np.array([float(m.group(1)), float(m.group(2))]), close_at)
        self.step += EXECUTED
        return {"actions": acts}

    def _look(self, obs: dict) -> np.ndarray | None:
        """The ball's centre (3,) metres as perceived in this observation's image, or None."""
        return perceive_ball(
            np.asarray(obs["observation/exterior_image_1_left"]), obs["toy/intrinsics"], obs["toy/world_to_cv"], self.R
        )

    def _after_grasp(self, obs: dict) -> None:
        """What a policy does on a call after its gripper has started to close (this one: nothing, it does not
        look again)."""

    def _plan(self, ee: np.ndarray, place_xy: np.ndarray, close_at: int) -> np.ndarray:
        R, lift = self.R, 2 * self.R + 0.25 * self.scale
        grasp = np.array([self.ball[0] + self.aim[0], self.ball[1] + self.aim[1], 2 * R])
        place = np.array([place_xy[0], place_xy[1], 2 * R])
        t0 = self.t0
        keys = [
            (t0 + 14, grasp),
            (t0 + 17, grasp),
            (t0 + 26, grasp + [0, 0, lift]),
            (t0 + 35, place + [0, 0, lift]),
            (t0 + 40, place),
            (t0 + 41, place),
            (t0 + 48, place + [0, 0, lift]),
        ]
        out = np.empty((HORIZON, 4))
        for i in range(HORIZON):
            t = self.step + i + 1
            start_t, start_p = self.step, ee  # the segment under way starts from where the arm is now
            pos = keys[-1][1]
            for k, (end_t, target) in enumerate(keys):
                if t <= end_t:
                    if k > 0 and keys[k - 1][0] >= self.step:
                        start_t, start_p = keys[k - 1]
                    pos = _min_jerk(start_p, target, (t - start_t) / max(end_t - start_t, 1))
                    break
            closed = self.closes and t0 + close_at <= t < t0 + 41
            out[i] = np.append(pos, 1.0 if closed else 0.0)
        return out


class ExactPolicy(ToyPickPlace):
    """Sees the ball where it is, closes on time."""


class NoisyPolicy(ToyPickPlace):
    """Perceives the ball 1.5 ball radii off (per axis, drawn per episode)."""

    aim_sigma_radii = 1.5


class LatePolicy(ToyPickPlace):
    """Closes the gripper 1–6 steps late (drawn per episode)."""

    close_delay = (1, 6)


class NeverClosesPolicy(ToyPickPlace):
    """Goes through the motions without ever closing the gripper."""

    closes = False


class RetryPolicy(ToyPickPlace):
    """Aims as ``noisy`` does, looks at the ball on every call, and once the lift should have taken the ball
    along (:attr:`verify_after` steps into the attempt) checks: a ball still lying within :attr:`retry_radii`
    ball radii of where it was is a missed grasp, so the gripper opens and a new attempt starts from there (a
    new aim drawn), up to :attr:`retries` times. Its success depends on what it sees after the grasp: in a
    world model, on whether the generated ball stayed or came along."""

    aim_sigma_radii = 1.5
    retries = 1
    verify_after = 32  # steps: the lift ends at 26; with 16-frame chunks the call at 32 sees frame 32
    retry_radii = 1.0

    def reset(self) -> None:
        super().reset()
        self.left = self.retries
        self.checked = False

    def _after_grasp(self, obs: dict) -> None:
        if self.checked or self.left <= 0 or self.ball is None or self.step - self.t0 < self.verify_after:
            return
        self.checked = True
        seen = self._look(obs)
        if seen is None or np.linalg.norm(seen[:2] - self.ball[:2]) > self.retry_radii * self.R:
            return  # gone from where it lay: carried (or pushed away); go on with the place
        self.left -= 1
        self.t0, self.checked, self.ball = self.step, False, seen
        self.aim = self.rng.normal(0.0, self.aim_sigma_radii, 2) * self.R


class RetryFarPolicy(RetryPolicy):
    """:class:`RetryPolicy` with an aim twice as poor (3 ball radii per axis): it misses most first attempts
    and needs its retry."""

    aim_sigma_radii = 3.0


class RandomPolicy(ToyPickPlace):
    """Random reachable end-effector waypoints and a random gripper."""

    def infer(self, obs: dict) -> dict:
        if self.rng is None:
            self._setup(obs)
        q = np.asarray(obs["observation/joint_position"], float)
        ee = self.ik.pose(q)[:3, 3]
        target = ee + self.rng.normal(0.0, 0.3 * self.scale, 3)
        target[2] = max(target[2], self.R)
        grip = float(self.rng.integers(0, 2))
        acts = np.array([np.append(_min_jerk(ee, target, (i + 1) / HORIZON), grip) for i in range(HORIZON)])
        self.step += EXECUTED
        return {"actions": acts}


#: name → ``module:attr`` of the toy policies, best first.
POLICIES = {
    "exact": f"{__name__}:ExactPolicy",
    "noisy": f"{__name__}:NoisyPolicy",
    "late": f"{__name__}:LatePolicy",
    "never_closes": f"{__name__}:NeverClosesPolicy",
    "random": f"{__name__}:RandomPolicy",
    "retry": f"{__name__}:RetryPolicy",
    "retry_far": f"{__name__}:RetryFarPolicy",
}
#: The policies of the closed-loop sessions before the re-perceiving ones were added (their default list).
CLASSIC = ("exact", "noisy", "late", "never_closes", "random")


def policy_specs(names=None) -> list[dict]:
    """Closed-loop manifest entries of the toy policies ``names`` (default: the :data:`CLASSIC` five, best first;
    the re-perceiving ones are asked for by name)."""
    return [{"name": n, "policy": POLICIES[n], **SPEC} for n in (names or CLASSIC)]
