"""The Franka Panda arm with a Robotiq 2F-85 instead of the Franka Hand (DROID, RoboArena).

Registered as its own embodiment, ``franka_robotiq``, by the franka plugin's
hook: the same seven arm joints as ``franka``, another tool. Its kinematic
tree is the Panda URDF of ``example-robot-data`` with everything below the
flange (``panda_link8``: the hand, its fingers and TCP) removed and the
kinematics-only Robotiq 2F-85 of ``assets/robotiq_2f85.urdf.xacro``
attached to the flange. Provenance of every number: ``README.md``,
"Robotiq 2F-85".
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

from oscar_core import CameraSpec, Embodiment, Gripper, Skeleton
from oscar_core.urdf import KinematicTree

__all__ = [
    "FrankaRobotiq",
    "ROBOTIQ_XACRO",
    "FLANGE",
    "COUPLING_LENGTH",
    "COUPLING_YAW",
    "ROBOTIQ_CLOSED",
    "build_franka_robotiq_tree",
]

ASSETS = Path(__file__).resolve().parent / "assets"
ROBOTIQ_XACRO = ASSETS / "robotiq_2f85.urdf.xacro"
#: the Panda's flange link: the tool is attached here
FLANGE = "panda_link8"
#: flange → Robotiq base along the flange z axis, metres (the coupling plate; an estimate, README)
COUPLING_LENGTH = 0.011
#: rotation of the Robotiq base about the flange z axis, radians: the Franka Hand's own
#: (``panda_hand_joint`` rpy 0 0 -π/4), so the jaw closes along the same axis as the hand's
COUPLING_YAW = -math.pi / 4
#: ``finger_joint`` (outer knuckle) angle, radians, at the Robotiq's closed end: the
#: upper limit of ROS-Industrial's description (0 = fully open)
ROBOTIQ_CLOSED = 0.8


def build_franka_robotiq_tree(
    panda_urdf: str | Path | None = None, coupling_length: float = COUPLING_LENGTH, coupling_yaw: float = COUPLING_YAW
) -> KinematicTree:
    """The Panda arm with the Robotiq 2F-85 on its flange, as one :class:`KinematicTree`.

    panda_urdf: the Panda URDF (default: the one in ``example-robot-data``).
    Every link below ``panda_link8`` and the joints leading to them are
    dropped; the Robotiq's links and joints (``ROBOTIQ_XACRO`` expanded with
    ``parent=panda_link8``, ``coupling_length`` metres, ``coupling_yaw``
    radians) are added. Meshes are never opened.
    """
    from lxml import etree

    from oscar_core.urdf import build_tree_from_urdf_string, expand_xacro

    from ._panda_urdf import panda_urdf_path

    panda_urdf = Path(panda_urdf) if panda_urdf is not None else panda_urdf_path()
    robot = etree.fromstring(
        panda_urdf.read_bytes(), parser=etree.XMLParser(remove_comments=True, resolve_entities=False)
    )
    children: dict[str, list[str]] = {}
    for j in robot.findall("joint"):
        children.setdefault(j.find("parent").get("link"), []).append(j.find("child").get("link"))
    below, stack = set(), list(children.get(FLANGE, []))
    while stack:
        link = stack.pop()
        below.add(link)
        stack += children.get(link, [])
    for el in list(robot):
        if el.tag == "link" and el.get("name") in below:
            robot.remove(el)
        elif (
            el.tag in ("joint", "transmission")
            and el.find("child") is not None
            and el.find("child").get("link") in below
        ):
            robot.remove(el)
        elif el.tag in ("transmission", "gazebo"):  # not kinematics; may name the removed joints
            robot.remove(el)
    args = {
        "parent": FLANGE,
        "coupling_length": repr(float(coupling_length)),
        "coupling_yaw": repr(float(coupling_yaw)),
    }
    gripper = etree.fromstring(expand_xacro(ROBOTIQ_XACRO, args).encode())
    for el in gripper:
        if el.tag in ("link", "joint"):
            robot.append(el)
    return build_tree_from_urdf_string(etree.tostring(robot), f"{panda_urdf} (below {FLANGE}: {ROBOTIQ_XACRO.name})")


class _ArmURDF:
    """``urdf`` of the arm, resolved on first use (see :func:`panda_urdf_path`); the
    tree itself is :func:`build_franka_robotiq_tree`."""

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        from ._panda_urdf import panda_urdf_path

        return panda_urdf_path()

    def __repr__(self):
        return f"<panda.urdf from example-robot-data + {ROBOTIQ_XACRO.name} at {FLANGE}>"


_ARM = ("panda_link0", "panda_link1", "panda_link3", "panda_link4", "panda_link5", "panda_link7")
_TOOL = ("robotiq_base", "left_outer_finger", "right_outer_finger", "left_inner_finger_pad", "right_inner_finger_pad")
#: palm point: the height of the knuckle pivots above the Robotiq base (finger_joint origin z)
PALM = (0.0, 0.0, 0.054904)


class FrankaRobotiq(Embodiment):
    """Franka Emika Panda (7-DoF arm) with a Robotiq 2F-85 adaptive gripper."""

    name = "franka_robotiq"
    description = "Franka Emika Panda with a Robotiq 2F-85 gripper (DROID, RoboArena)"
    license = "Apache-2.0 AND BSD-2-Clause"
    datasets = ("droid", "roboarena")
    urdf = _ArmURDF()
    skeleton = Skeleton(
        links=_ARM + _TOOL,
        points={"robotiq_base": PALM},
        groups={"arm": _ARM, "hand": _TOOL},
    )
    # Signal: DROID's gripper position, 0 = open .. 1 = closed (Robotiq position / 255).
    # It drives finger_joint linearly from 0.8 rad (closed) to 0 (open); the other
    # knuckle and both inner fingers mimic it. The indicator sits on the coupling.
    grippers = (
        Gripper(
            "gripper",
            link="robotiq_base",
            point=(0.0, 0.0, 0.0),
            signal_range=(0.0, 1.0),
            closed_at="high",
            joint="finger_joint",
            joint_range=(ROBOTIQ_CLOSED, 0.0),
        ),
    )
    end_effector_links = ("robotiq_base",)  # the gripper's link (latent-action baseline)
    camera = CameraSpec(convention="opencv", direction="camera_to_world", mount_link=None)
    example_trajectory = ASSETS / "example_trajectory_robotiq.npz"
    example_camera = ASSETS / "example_camera_robotiq.json"

    @functools.cached_property
    def tree(self) -> KinematicTree:
        """The Panda arm with the Robotiq 2F-85 on its flange (:func:`build_franka_robotiq_tree`)."""
        return build_franka_robotiq_tree()
