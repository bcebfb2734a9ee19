"""One policy protocol for in-process and remote policies, and the checks every answer goes through.

The protocol is openpi's ``BasePolicy``: ``infer(observation: dict) -> {"actions": (H, D)}`` and an optional
``reset()`` called at the start of each episode. What the protocol cannot carry is declared per policy in a
:class:`PolicySpec`: the action space, the control rate, the image size, how many actions are executed per call,
and which observation keys the policy reads (DROID's by default, :data:`DROID_KEYS`).

A policy is untrusted input. :func:`call_policy` runs one ``infer`` under a timeout and :func:`check_answer`
checks what came back (a dict with ``"actions"``; a float array of shape (H, D) with D the action space's width
and H at least the number of actions executed; every value finite and not absurdly outside the robot's limits,
:func:`absurd_bounds`). Any problem raises :class:`PolicyFault` with a one-line reason, which ends that episode
only.

:func:`oscar_core.policy.loading.load_policy` finds a policy by its source.
"""

from __future__ import annotations

import concurrent.futures
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol, get_args, runtime_checkable

import numpy as np

from ..errors import OscarError

__all__ = [
    "ActionSpaceName",
    "GripperMode",
    "ACTION_SPACES",
    "GRIPPER_MODES",
    "DROID_KEYS",
    "OBS_FIELDS",
    "ENTRY_POINT_GROUP",
    "Policy",
    "PolicySpec",
    "PolicyFault",
    "PolicySpecError",
    "action_width",
    "check_answer",
    "call_policy",
    "absurd_bounds",
]

#: Action spaces a policy may declare (:mod:`oscar_core.policy.spaces`).
ActionSpaceName = Literal[
    "joint_position", "joint_velocity", "joint_delta", "ee_pose", "ee_delta", "ee_position", "ee_position_delta"
]
ACTION_SPACES: tuple[str, ...] = get_args(ActionSpaceName)
#: How the last action column drives the gripper: its closure in [0, 1] (1 = closed, DROID's convention), or
#: the same thresholded at 0.5.
GripperMode = Literal["position", "binary"]
GRIPPER_MODES: tuple[str, ...] = get_args(GripperMode)

#: The observation fields the loop fills, and DROID's key for each (openpi's DROID example).
OBS_FIELDS = ("image", "wrist_image", "joint_position", "gripper_position", "prompt")
DROID_KEYS: Mapping[str, str] = {
    "image": "observation/exterior_image_1_left",
    "wrist_image": "observation/wrist_image_left",
    "joint_position": "observation/joint_position",
    "gripper_position": "observation/gripper_position",
    "prompt": "prompt",
}
ENTRY_POINT_GROUP = "oscar.policies"

# what the checks call "absurd": this many joint ranges outside the limits (positions), this many ranges per
# second (velocities), this many metres from the robot's base (end-effector positions)
ABSURD_RANGES = 1.0
ABSURD_VELOCITY_RANGES_PER_S = 10.0
ABSURD_EE_METRES = 10.0


class PolicyFault(OscarError):
    """A policy failed one call: an exception, a timeout, or a malformed answer. ``reason`` is one line."""

    def __init__(self, reason: str):
        self.reason = reason
        super().__init__(reason)

    def __reduce__(self):
        return (type(self), (self.reason,))


class PolicySpecError(OscarError, ValueError):
    """A policy declaration is malformed; the message names the source, the field, what was expected and found."""

    def __init__(self, source, field_name, expected, found):
        super().__init__(f"{source}: field '{field_name}': expected {expected}, found {found}")


@runtime_checkable
class Policy(Protocol):
    """openpi's policy protocol: ``infer(obs) -> {"actions": (H, D)}``; ``reset()`` is optional."""

    def infer(self, obs: dict) -> dict: ...


def action_width(space: str, joints: int) -> int:
    """D of an action row in ``space`` for a robot of ``joints`` arm joints: the arm part plus one gripper column."""
    arm = {
        "joint_position": joints,
        "joint_velocity": joints,
        "joint_delta": joints,
        "ee_pose": 6,
        "ee_delta": 6,
        "ee_position": 3,
        "ee_position_delta": 3,
    }[space]
    return arm + 1


@dataclass(frozen=True)
class PolicySpec:
    """What a policy declares beside the protocol.

    name: the policy's name in the run (letters, digits, ``. _ -``); source: ``module:attr``, ``file.py:attr``,
    an entry-point name, or ``ws://host:port`` for a remote policy. action_space: :data:`ACTION_SPACES`;
    control_hz: actions per second; image_size: (width, height) pixels of the images the policy is sent;
    actions_per_call: actions executed per call (openpi's "open-loop horizon"; DROID policies usually 8);
    gripper: :data:`GRIPPER_MODES`; keys: {field: key} of the observation dict (:data:`OBS_FIELDS`; default DROID's);
    ee_rotation: for ``ee_pose``/``ee_delta``, the rotation's form (``rotvec``: axis × angle, radians).
    """

    name: str
    source: str
    action_space: ActionSpaceName = "joint_velocity"
    control_hz: float = 15.0
    image_size: tuple[int, int] = (224, 224)
    actions_per_call: int = 8
    gripper: GripperMode = "position"
    keys: Mapping[str, str] = field(default_factory=lambda: dict(DROID_KEYS))
    timeout_s: float = 30.0

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "source": self.source,
            "action_space": self.action_space,
            "control_hz": self.control_hz,
            "image_size": list(self.image_size),
            "actions_per_call": self.actions_per_call,
            "gripper": self.gripper,
            "keys": dict(self.keys),
            "timeout_s": self.timeout_s,
        }

    @classmethod
    def from_dict(cls, data: Mapping, source: str = "<policy>") -> PolicySpec:
        """Check and build a spec from a manifest entry (``name`` and ``policy`` required; the rest default to
        DROID's values). Raises :class:`PolicySpecError` naming ``source`` and the field."""
        if not isinstance(data, Mapping):
            raise PolicySpecError(source, "policy", "an object", type(data).__name__)
        allowed = {
            "name",
            "policy",
            "action_space",
            "control_hz",
            "image_size",
            "actions_per_call",
            "gripper",
            "keys",
            "timeout_s",
        }
        extra = sorted(set(data) - allowed)
        if extra:
            raise PolicySpecError(source, "keys", f"only {sorted(allowed)}", f"unknown keys {extra}")
        name, src = data.get("name"), data.get("policy")
        if not isinstance(name, str) or not name or not all(c.isalnum() or c in "._-" for c in name):
            raise PolicySpecError(source, "name", "a name of letters, digits, '.', '_' or '-'", repr(name))
        if not isinstance(src, str) or not src:
            raise PolicySpecError(
                source, "policy", "module:attr, file.py:attr, an entry-point name or ws://host:port", repr(src)
            )
        space = data.get("action_space", "joint_velocity")
        if space not in ACTION_SPACES:
            raise PolicySpecError(source, "action_space", f"one of {list(ACTION_SPACES)}", repr(space))
        gripper = data.get("gripper", "position")
        if gripper not in GRIPPER_MODES:
            raise PolicySpecError(source, "gripper", f"one of {list(GRIPPER_MODES)}", repr(gripper))
        hz = data.get("control_hz", 15.0)
        if isinstance(hz, bool) or not isinstance(hz, (int, float)) or not np.isfinite(hz) or hz <= 0:
            raise PolicySpecError(source, "control_hz", "a positive number (actions per second)", repr(hz))
        k = data.get("actions_per_call", 8)
        if isinstance(k, bool) or not isinstance(k, int) or k < 1:
            raise PolicySpecError(source, "actions_per_call", "an integer >= 1", repr(k))
        size = data.get("image_size", [224, 224])
        if (
            not isinstance(size, (list, tuple))
            or len(size) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)
        ):
            raise PolicySpecError(source, "image_size", "[width, height], positive integers", repr(size))
        keys = data.get("keys", {})
        if not isinstance(keys, Mapping) or not all(k in OBS_FIELDS and isinstance(v, str) for k, v in keys.items()):
            raise PolicySpecError(
                source, "keys", f"an object mapping some of {list(OBS_FIELDS)} to key strings", repr(keys)
            )
        timeout = data.get("timeout_s", 30.0)
        if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not timeout > 0:
            raise PolicySpecError(source, "timeout_s", "a positive number of seconds", repr(timeout))
        return cls(
            name=name,
            source=src,
            action_space=space,
            control_hz=float(hz),
            image_size=(size[0], size[1]),
            actions_per_call=k,
            gripper=gripper,
            keys={**DROID_KEYS, **keys},
            timeout_s=float(timeout),
        )


def absurd_bounds(space: str, lo: np.ndarray, hi: np.ndarray, hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(D,) lower and upper bounds beyond which an action value in ``space`` is "absurd" (a broken policy, not a
    clip): positions more than :data:`ABSURD_RANGES` joint ranges outside the limits ``lo``/``hi`` (J,);
    velocities above :data:`ABSURD_VELOCITY_RANGES_PER_S` ranges per second; deltas above one range per action;
    end-effector positions beyond :data:`ABSURD_EE_METRES`; rotations beyond 4π; the gripper outside [-1, 2]."""
    span = np.asarray(hi, float) - np.asarray(lo, float)
    if space == "joint_position":
        a, b = lo - ABSURD_RANGES * span, hi + ABSURD_RANGES * span
    elif space == "joint_velocity":
        v = ABSURD_VELOCITY_RANGES_PER_S * span
        a, b = -v, v
    elif space == "joint_delta":
        a, b = -span, span
    else:
        m = ABSURD_EE_METRES
        pos = np.full(3, m)
        rot = np.full(3 if space in ("ee_pose", "ee_delta") else 0, 4 * np.pi)
        b = np.concatenate([pos, rot])
        a = -b
    return np.append(a, -1.0), np.append(b, 2.0)


def check_answer(
    answer: Any, *, width: int, min_horizon: int, bounds: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """The (H, D) float64 actions of a policy's ``answer``, or :class:`PolicyFault` saying what is wrong.

    width: D; min_horizon: the fewest rows accepted (the actions executed per call); bounds: (D,) lower and
    upper "absurd" bounds (:func:`absurd_bounds`), or None.
    """
    if not isinstance(answer, Mapping):
        raise PolicyFault(f"answer: expected a dict with 'actions', found {type(answer).__name__}")
    if "actions" not in answer:
        raise PolicyFault(f"answer: expected a dict with 'actions', found keys {sorted(map(str, answer))[:8]}")
    raw = answer["actions"]
    try:
        arr = np.asarray(raw)
    except Exception as exc:  # noqa: BLE001 - anything a policy returns
        raise PolicyFault(
            f"actions: expected an (H, {width}) float array, found {type(raw).__name__} ({exc})"
        ) from None
    if arr.dtype.kind not in "fiu" or arr.dtype == bool:
        raise PolicyFault(f"actions: expected an (H, {width}) float array, found dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != width:
        raise PolicyFault(f"actions: expected shape (H, {width}), found {arr.shape}")
    if arr.shape[0] < min_horizon:
        raise PolicyFault(
            f"actions: expected at least {min_horizon} rows (actions executed per call), found {arr.shape[0]}"
        )
    arr = arr.astype(np.float64)
    bad = ~np.isfinite(arr)
    if bad.any():
        r, c = (int(v) for v in np.argwhere(bad)[0])
        raise PolicyFault(
            f"actions: expected finite values, found {arr[r, c]} at row {r}, column {c} ({int(bad.sum())} values)"
        )
    if bounds is not None:
        lo, hi = bounds
        out = (arr < lo) | (arr > hi)
        if out.any():
            r, c = (int(v) for v in np.argwhere(out)[0])
            raise PolicyFault(
                f"actions: expected values within [{lo[c]:.4g}, {hi[c]:.4g}] in column {c} (beyond "
                f"that no robot goes), found {arr[r, c]:.6g} at row {r}"
            )
    return arr


class _Caller:
    """One daemon thread per call (a policy that never returns leaves a thread behind, never a hung run)."""

    def __call__(self, fn, arg, timeout: float):
        box: dict = {}

        def run():
            try:
                box["value"] = fn(arg)
            except BaseException as exc:  # noqa: BLE001 - reported as the fault's reason
                box["error"] = exc

        t = threading.Thread(target=run, name="oscar-policy-call", daemon=True)
        t.start()
        t.join(timeout)
        if t.is_alive():
            raise concurrent.futures.TimeoutError
        if "error" in box:
            raise box["error"]
        return box["value"]


_call = _Caller()


def call_policy(policy, obs: dict, timeout_s: float) -> tuple[Any, float]:
    """``(answer, seconds)`` of ``policy.infer(obs)``; :class:`PolicyFault` on an exception or after ``timeout_s``
    seconds (the call's thread is left to finish on its own; its answer is dropped)."""
    t0 = time.perf_counter()
    try:
        answer = _call(policy.infer, obs, timeout_s)
    except concurrent.futures.TimeoutError:
        raise PolicyFault(f"infer: expected an answer within {timeout_s:g} s (policy timeout), found none") from None
    except PolicyFault:
        raise
    except Exception as exc:  # noqa: BLE001 - a policy's own exception is its fault's reason
        text = str(exc).strip().splitlines()
        raise PolicyFault(f"infer raised {type(exc).__name__}: {text[0][:300] if text else ''}") from None
    return answer, time.perf_counter() - t0
