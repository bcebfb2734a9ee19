"""Gymnasium spaces of a closed-loop episode, derived from the sessions, the embodiment and the declared policy.

* the **action space**: one action row of the declared action space (:mod:`oscar_core.policy.spaces`), a
  ``Box`` of shape (D,) float64 whose bounds are the loop's own acceptance bounds
  (:func:`~oscar_core.policy.protocol.absurd_bounds`: joint limits widened by one range, velocities of ten
  ranges per second, 10 m, 4π, the gripper in [-1, 2]). Values inside the box but past the joint limits are
  executed clipped and counted, as ``oscar eval closed-loop`` does; values outside it are refused
  (:func:`check_action`).
* the **observation space**: a ``Dict`` under the policy's observation keys (DROID's by default): the image and
  the (black) wrist image, ``Box(0, 255, (H, W, 3), uint8)`` at the declared ``image_size``; the joint
  positions, ``Box`` of the joint limits (J,) float64; the gripper closure, ``Box(0, 1, (1,))``; the task,
  ``Text``; and every session ``extras`` key, a ``Text`` for a string, a float64 ``Box`` for numbers.
"""

from __future__ import annotations

import string

import numpy as np

from .._util.optional import require
from ..errors import OscarError

__all__ = ["ActionSpaceError", "action_columns", "action_space_of", "observation_space_of", "check_action"]


class ActionSpaceError(OscarError, ValueError):
    """An action outside the declared action space; the message is one line naming the column."""


def action_columns(space: str, emb) -> list[str]:
    """Names of an action row's columns in ``space`` for ``emb``: its joints or the end-effector's coordinates,
    then ``gripper``."""
    arm = {
        "ee_pose": ["x", "y", "z", "rx", "ry", "rz"],
        "ee_delta": ["dx", "dy", "dz", "drx", "dry", "drz"],
        "ee_position": ["x", "y", "z"],
        "ee_position_delta": ["dx", "dy", "dz"],
    }.get(space, list(emb.joint_names))
    return arm + ["gripper"]


def action_space_of(adapter):
    """The ``Box`` of one action row of ``adapter``'s declared space (module docstring)."""
    spaces = require("gymnasium", "gym").spaces
    lo, hi = adapter.bounds()
    return spaces.Box(lo.astype(np.float64), hi.astype(np.float64), dtype=np.float64)


def check_action(action, box, columns: list[str], space_name: str) -> np.ndarray:
    """``action`` as a (D,) float64 row, or :class:`ActionSpaceError` naming what is wrong (shape, a non-finite
    value, a value outside the box and its column)."""
    try:
        a = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ActionSpaceError(f"action: expected {box.shape[0]} numbers ({space_name}), found {exc}") from None
    if a.shape != box.shape:
        raise ActionSpaceError(
            f"action: expected shape {box.shape} ({space_name}: {' '.join(columns)}), found {a.shape}"
        )
    for k in range(a.shape[0]):
        if not np.isfinite(a[k]) or not box.low[k] <= a[k] <= box.high[k]:
            raise ActionSpaceError(
                f"action[{k}] ({columns[k]}): expected a value in [{box.low[k]:.4g}, {box.high[k]:.4g}] "
                f"(the declared {space_name} space), found {a[k]:.6g}"
            )
    return a


def _extra_space(key: str, values: list, where: str):
    spaces = require("gymnasium", "gym").spaces
    if all(isinstance(v, str) for v in values):
        return spaces.Text(max(len(v) for v in values), min_length=0, charset=_charset(values))
    shapes = set()
    for v in values:
        try:
            arr = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            arr = None
        if arr is None or isinstance(v, (bool, dict)):
            raise OscarError(
                f"{where}: extras[{key!r}]: expected a string or numbers (the observation holds it as Text or "
                f"Box), found {type(v).__name__}"
            )
        shapes.add(arr.shape)
    if len(shapes) != 1:
        raise OscarError(f"{where}: extras[{key!r}]: expected one shape in every session, found {sorted(shapes)}")
    return spaces.Box(-np.inf, np.inf, shapes.pop(), dtype=np.float64)


def _charset(texts: list[str]) -> frozenset:
    return frozenset(string.printable).union(*[set(t) for t in texts])


def observation_space_of(spec, emb, sessions, where: str = "<manifest>"):
    """The ``Dict`` observation space (module docstring) for the policy declaration ``spec``, the embodiment
    ``emb`` and ``sessions`` (each with ``task`` and ``extras``; every session must hold the same extras keys)."""
    from ..kinematics.workspace import joint_limits

    spaces = require("gymnasium", "gym").spaces
    w, h = spec.image_size
    lo, hi = joint_limits(emb, shrink=0.0)
    keys = spec.keys
    tasks = [s.task for s in sessions]
    out = {
        keys["image"]: spaces.Box(0, 255, (h, w, 3), dtype=np.uint8),
        keys["wrist_image"]: spaces.Box(0, 255, (h, w, 3), dtype=np.uint8),
        keys["joint_position"]: spaces.Box(np.asarray(lo, np.float64), np.asarray(hi, np.float64), dtype=np.float64),
        keys["gripper_position"]: spaces.Box(0.0, 1.0, (1,), dtype=np.float64),
        keys["prompt"]: spaces.Text(max(len(t) for t in tasks), min_length=0, charset=_charset(tasks)),
    }
    extra_keys = {tuple(sorted(s.extras)) for s in sessions}
    if len(extra_keys) != 1:
        raise OscarError(f"{where}: extras: expected the same keys in every session, found {sorted(extra_keys)}")
    for key in extra_keys.pop():
        if key in out:
            raise OscarError(f"{where}: extras[{key!r}]: expected a key the observation does not use, found it used")
        out[key] = _extra_space(key, [s.extras[key] for s in sessions], where)
    return spaces.Dict(out)


def extras_as_values(extras: dict, space) -> dict:
    """The session's extras as the observation space holds them (numbers as float64 arrays)."""
    spaces = require("gymnasium", "gym").spaces
    return {k: (np.asarray(v, dtype=np.float64) if isinstance(space[k], spaces.Box) else v) for k, v in extras.items()}
