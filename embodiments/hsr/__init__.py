"""oscar embodiment plugin: Toyota HSR-B (AIROA-MoMa).

Written as an outside plugin would be: this module, ``assets/`` and the entry
point ``hsr = "oscar_embodiments.hsr"``. Provenance of every number, the joint
order, units, the gripper signal and the camera convention are in
``README.md`` beside this file; dataset adapters are in :mod:`.adapters`.

Joint order of trajectories (7 joints, radians except the arm lift in metres)::

    arm_lift_joint (m), arm_flex_joint, arm_roll_joint, wrist_flex_joint,
    wrist_roll_joint, head_pan_joint, head_tilt_joint (+ looks up)

``torso_lift_joint`` is not given: it mimics the arm lift (half of it), as on
the robot. The planar base pose (x, y, yaw) of ``base_footprint`` is the
trajectory's ``base_pose`` (see :func:`base_pose_from_xy_yaw`); without one
the robot stands at the world origin.

Gripper signal (G = 1, ``hand``): the ``hand_motor_joint`` angle in radians,
-0.798 … 1.24 (the reference's limits; larger is more open). The fingertips
meet at 0; below 0 the motor squeezes against the finger springs, so openness
is 0 for every value <= 0 and the fingers are drawn closed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from oscar_core import CameraSpec, Embodiment, Gripper, Skeleton, hookimpl

__all__ = [
    "HSR",
    "JOINTS",
    "HEAD_CAMERA_LINK",
    "HAND_RANGE",
    "HAND_CONTACT",
    "base_pose_from_xy_yaw",
    "oscar_register_embodiments",
]

ASSETS = Path(__file__).parent / "assets"

#: the trajectory joint order (``HSR().joint_names``)
JOINTS = (
    "arm_lift_joint",
    "arm_flex_joint",
    "arm_roll_joint",
    "wrist_flex_joint",
    "wrist_roll_joint",
    "head_pan_joint",
    "head_tilt_joint",
)
#: hand_motor_joint limits of the reference, radians: (closed, open)
HAND_RANGE = (-0.798, 1.24)
#: hand_motor_joint angle at which the fingertips meet (their frames are 4 mm
#: apart in the reference kinematics with the finger springs at rest)
HAND_CONTACT = 0.0
#: the head RGB-D sensor's optical frame (x right, y down, z forward)
HEAD_CAMERA_LINK = "head_rgbd_sensor_link"

_BASE = ("base_footprint", "base_range_sensor_link")
_TORSO = ("torso_lift_link", "head_tilt_link", "head_rgbd_sensor_link")
_ARM = ("arm_lift_link", "arm_flex_link", "wrist_flex_link", "hand_palm_link")
_HAND = ("hand_l_proximal_link", "hand_l_finger_tip_frame", "hand_r_proximal_link", "hand_r_finger_tip_frame")


def base_pose_from_xy_yaw(x, y, yaw) -> np.ndarray:
    """Planar base poses: x, y (T,) metres and yaw (T,) radians → (T, 4, 4).

    The pose of ``base_footprint`` in the world (odometry) frame: a rotation
    of ``yaw`` about the vertical axis and a translation (x, y, 0). Scalars
    broadcast against arrays; all three must have one shape (T,) otherwise.
    """
    x, y, yaw = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, dtype=np.float64)) for v in (x, y, yaw)))
    if x.ndim != 1:
        raise ValueError(f"base_pose_from_xy_yaw: expected x, y, yaw of shape (T,), found {x.shape}")
    if not (np.isfinite(x).all() and np.isfinite(y).all() and np.isfinite(yaw).all()):
        raise ValueError("base_pose_from_xy_yaw: expected finite x, y, yaw")
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.zeros((x.shape[0], 4, 4))
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -s, s, c
    T[:, 2, 2] = T[:, 3, 3] = 1.0
    T[:, 0, 3], T[:, 1, 3] = x, y
    return T


class HSR(Embodiment):
    """Toyota HSR-B: omnidirectional base, 5-DoF arm on a lift, pan-tilt head, two-finger hand."""

    name = "hsr"
    description = "Toyota HSR-B mobile manipulator with a head RGB-D camera (AIROA-MoMa)"
    license = "BSD-3-Clause-Clear"
    datasets = ("airoa_moma",)
    xacro = ASSETS / "hsrb.urdf.xacro"
    skeleton = Skeleton(
        links=_BASE + _ARM + _TORSO + _HAND,
        # Given explicitly: the arm and the head column both rise from the
        # base axis; collapsing the tree would draw them as two overlapping
        # vertical lines from the floor.
        edges=(
            ("base_footprint", "base_range_sensor_link"),
            ("base_footprint", "arm_lift_link"),
            ("arm_lift_link", "arm_flex_link"),
            ("arm_flex_link", "wrist_flex_link"),
            ("wrist_flex_link", "hand_palm_link"),
            ("arm_lift_link", "torso_lift_link"),
            ("torso_lift_link", "head_tilt_link"),
            ("head_tilt_link", "head_rgbd_sensor_link"),
            ("hand_palm_link", "hand_l_proximal_link"),
            ("hand_l_proximal_link", "hand_l_finger_tip_frame"),
            ("hand_palm_link", "hand_r_proximal_link"),
            ("hand_r_proximal_link", "hand_r_finger_tip_frame"),
        ),
        groups={"base": _BASE, "arm": _ARM, "torso_head": _TORSO, "hand": _HAND},
        colors={"base": (140, 100, 255), "arm": (255, 170, 0), "torso_head": (255, 60, 200), "hand": (0, 170, 255)},
    )
    # the indicator sits between the fingertips (9 cm out of the palm)
    end_effector_links = ("hand_palm_link",)  # the gripper's link (latent-action baseline)
    grippers = (
        Gripper(
            "hand",
            link="hand_palm_link",
            point=(0.0, 0.0, 0.09),
            signal_range=HAND_RANGE,
            closed_at="low",
            joint="hand_motor_joint",
            joint_range=(HAND_CONTACT, HAND_RANGE[1]),
        ),
    )
    camera = CameraSpec(convention="opencv", direction="camera_to_world", mount_link=HEAD_CAMERA_LINK)
    example_trajectory = ASSETS / "example_trajectory.npz"
    example_camera = ASSETS / "example_camera.json"

    # The hand is not linear over the motor's range: the fingertips meet at
    # hand_motor_joint = HAND_CONTACT, and below it the motor keeps turning
    # against the finger springs (passive joints, drawn at rest here), which
    # squeezes without closing further. So openness is 0 at contact and 1
    # fully open, and the finger joint (joint_range above) is drawn at
    # max(signal, HAND_CONTACT).
    def gripper_openness(self, gripper: np.ndarray, source: str = "<trajectory>") -> np.ndarray:
        super().gripper_openness(gripper, source)  # range check against HAND_RANGE (±5 %)
        span = HAND_RANGE[1] - HAND_CONTACT
        return np.clip((np.asarray(gripper, dtype=np.float64) - HAND_CONTACT) / span, 0.0, 1.0).reshape(-1, 1)


@hookimpl
def oscar_register_embodiments():
    return [HSR]
