"""Policies in the loop: one protocol for in-process and remote policies, declared action spaces, adapters.

* :mod:`oscar_core.policy.protocol` — openpi's ``infer(obs) -> {"actions": (H, D)}``, :class:`PolicySpec`,
  answer checks, timeouts, :class:`PolicyFault`, loading by ``module:attr`` or entry point;
* :mod:`oscar_core.policy.spaces` — action spaces → joint positions, resampling to a model's frame rate;
* :mod:`oscar_core.policy.loading` — a policy from ``module:attr``, an entry point or ``ws://host:port``;
* :mod:`oscar_core.policy.remote`, :mod:`oscar_core.policy.serve` — openpi's websocket protocol, client and server;
* :mod:`oscar_core.policy.lerobot` — LeRobot policies (``select_action``) behind the protocol, ``lerobot:`` sources;
* :mod:`oscar_core.policy.ik` — damped-least-squares IK on the project's forward kinematics.

Names are re-exported flat; submodules load on first use. See docs/closed-loop.md.
"""

from __future__ import annotations

from .._util.lazy import lazy_exports

_EXPORTS = {
    "ACTION_SPACES": "protocol",
    "GRIPPER_MODES": "protocol",
    "DROID_KEYS": "protocol",
    "Policy": "protocol",
    "PolicySpec": "protocol",
    "PolicyFault": "protocol",
    "PolicySpecError": "protocol",
    "check_answer": "protocol",
    "call_policy": "protocol",
    "load_policy": "loading",
    "action_width": "protocol",
    "ActionAdapter": "spaces",
    "AdapterResult": "spaces",
    "resample": "spaces",
    "resample_joints": "spaces",
    "LeRobotPolicy": "lerobot",
    "LeRobotMappingError": "lerobot",
    "EndEffectorIK": "ik",
    "IKResult": "ik",
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
