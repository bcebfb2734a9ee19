"""oscar embodiment plugin: AgiBot G1 with two Omnipicker grippers (AgiBot World).

Written as an outside plugin would be: this module, ``assets/`` and the entry
point ``agibot_g1 = "oscar_embodiments.agibot_g1"``. Provenance of every
number, the joint order, units, the gripper signal and the camera convention
are in ``README.md`` beside this file; dataset adapters are in
:mod:`.adapters`.

Joint order of trajectories (18 joints, radians except the lift in metres)::

    idx01_body_joint1 (waist lift, m), idx02_body_joint2 (waist pitch),
    idx11_head_joint1 (head yaw), idx12_head_joint2 (head pitch, + looks down),
    idx21..idx27_arm_l_joint1..7 (left arm), idx61..idx67_arm_r_joint1..7 (right arm)

Gripper signals (G = 2, order ``left_gripper, right_gripper``): AgiBot World's
``action/effector/position``, 0 = fully open, 1 = fully closed. Each drives the
outer finger joint of its Omnipicker (0 rad closed … π/4 rad open); the inner
finger mirrors it (a mimic joint).
"""

from __future__ import annotations

from pathlib import Path

from oscar_core import CameraSpec, Embodiment, Gripper, Skeleton, hookimpl

__all__ = ["AgiBotG1", "JOINTS", "LEFT_ARM", "RIGHT_ARM", "HEAD_CAMERA_LINK", "oscar_register_embodiments"]

ASSETS = Path(__file__).parent / "assets"

WAIST = ("idx01_body_joint1", "idx02_body_joint2")
HEAD = ("idx11_head_joint1", "idx12_head_joint2")
LEFT_ARM = tuple(f"idx2{i}_arm_l_joint{i}" for i in range(1, 8))
RIGHT_ARM = tuple(f"idx6{i}_arm_r_joint{i}" for i in range(1, 8))
#: the trajectory joint order (``AgiBotG1().joint_names``)
JOINTS = WAIST + HEAD + LEFT_ARM + RIGHT_ARM

#: the head camera rides on the last head link (the reference has no camera link)
HEAD_CAMERA_LINK = "head_link2"

# A finger's drawn point: the distal pivot of its driven link1 (where the
# passive link3 hangs in the reference), in the link1 frame. It moves in and
# out with the finger joint.
_OUTER_TIP = (0.030852, -0.018551, 0.0)
_INNER_TIP = (0.030852, 0.018551, 0.0)

_TORSO = ("base_link", "body_link1", "body_link2", "arm_base_link", "head_link1", "head_link2")
_LEFT = ("arm_l_link1", "arm_l_link3", "arm_l_link5", "arm_l_link7", "gripper_l_outer_link1", "gripper_l_inner_link1")
_RIGHT = ("arm_r_link1", "arm_r_link3", "arm_r_link5", "arm_r_link7", "gripper_r_outer_link1", "gripper_r_inner_link1")


class AgiBotG1(Embodiment):
    """AgiBot G1: waist lift + pitch, 2-DoF head, two 7-DoF arms, two Omnipickers."""

    name = "agibot_g1"
    description = "AgiBot G1 dual-arm robot with Omnipicker grippers and a head camera (AgiBot World)"
    license = "MPL-2.0"
    datasets = ("agibot_world",)
    urdf = ASSETS / "g1.urdf"
    skeleton = Skeleton(
        links=_TORSO + _LEFT + _RIGHT,
        points={
            "gripper_l_outer_link1": _OUTER_TIP,
            "gripper_l_inner_link1": _INNER_TIP,
            "gripper_r_outer_link1": _OUTER_TIP,
            "gripper_r_inner_link1": _INNER_TIP,
        },
        # Given explicitly: collapsing the tree would join the head and the
        # shoulders both to the waist joint, drawing two overlapping spines.
        edges=(
            ("base_link", "body_link1"),
            ("body_link1", "body_link2"),
            ("body_link2", "arm_base_link"),
            ("arm_base_link", "head_link1"),
            ("head_link1", "head_link2"),
            ("arm_base_link", "arm_l_link1"),
            ("arm_l_link1", "arm_l_link3"),
            ("arm_l_link3", "arm_l_link5"),
            ("arm_l_link5", "arm_l_link7"),
            ("arm_l_link7", "gripper_l_outer_link1"),
            ("arm_l_link7", "gripper_l_inner_link1"),
            ("arm_base_link", "arm_r_link1"),
            ("arm_r_link1", "arm_r_link3"),
            ("arm_r_link3", "arm_r_link5"),
            ("arm_r_link5", "arm_r_link7"),
            ("arm_r_link7", "gripper_r_outer_link1"),
            ("arm_r_link7", "gripper_r_inner_link1"),
        ),
        groups={"left_arm": _LEFT, "right_arm": _RIGHT, "torso_head": _TORSO},
        colors={"left_arm": (255, 170, 0), "right_arm": (0, 170, 255), "torso_head": (255, 60, 200)},
    )
    end_effector_links = (
        "gripper_l_center_link",
        "gripper_r_center_link",
    )  # the gripper's link (latent-action baseline)
    grippers = (
        Gripper(
            "left_gripper",
            link="gripper_l_center_link",
            signal_range=(0.0, 1.0),
            closed_at="high",
            joint="idx41_gripper_l_outer_joint1",
            joint_range=(0.0, 0.7853981633974483),
        ),
        Gripper(
            "right_gripper",
            link="gripper_r_center_link",
            signal_range=(0.0, 1.0),
            closed_at="high",
            joint="idx81_gripper_r_outer_joint1",
            joint_range=(0.0, 0.7853981633974483),
        ),
    )
    camera = CameraSpec(convention="opencv", direction="camera_to_world", mount_link=HEAD_CAMERA_LINK)
    # arm-only trajectories may leave out the waist and head: the reference's zero (README "Default pose")
    default_pose = {
        "idx01_body_joint1": 0.0,
        "idx02_body_joint2": 0.0,
        "idx11_head_joint1": 0.0,
        "idx12_head_joint2": 0.0,
    }
    example_trajectory = ASSETS / "example_trajectory.npz"
    example_camera = ASSETS / "example_camera.json"


@hookimpl
def oscar_register_embodiments():
    return [AgiBotG1]
