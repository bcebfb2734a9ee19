"""oscar embodiment plugin: Franka Emika Panda with the Franka Hand.

Datasets: DROID, RH20T cfg5, InternData-A1 (adapters in
:mod:`oscar_embodiments.franka.adapters`). The kinematics are the Panda URDF
shipped in the ``example-robot-data`` wheel (Apache-2.0), found through the
distribution's file list the first time the embodiment is used, so importing
this module stays cheap. Provenance, joint order, units and conventions:
``README.md``.
"""

from __future__ import annotations

from pathlib import Path

from oscar_core import CameraSpec, Embodiment, Gripper, Skeleton, hookimpl

from ._panda_urdf import URDF_DISTRIBUTION, URDF_SUFFIX, panda_urdf_path

__all__ = [
    "Franka",
    "ASSETS",
    "JOINT_NAMES",
    "URDF_DISTRIBUTION",
    "URDF_SUFFIX",
    "panda_urdf_path",
    "oscar_register_embodiments",
]

ASSETS = Path(__file__).resolve().parent / "assets"

#: Joint order of trajectories (radians); the finger joint is driven by the gripper signal.
JOINT_NAMES = tuple(f"panda_joint{i}" for i in range(1, 8))


class _PandaURDF:
    """``urdf`` attribute resolved on first use by an instance (see :func:`panda_urdf_path`)."""

    def __get__(self, obj, owner=None):
        if obj is None:  # class access (contract checks): the descriptor itself, not None
            return self
        return panda_urdf_path()

    def __repr__(self):
        return f"<{URDF_SUFFIX} from the {URDF_DISTRIBUTION!r} distribution>"


# Points: the paper's rule is the link origin. Panda link frames follow the
# modified-DH layout, so panda_link2 sits on panda_link1's origin and
# panda_link6 on panda_link5's for every q: those two add nothing and are left
# out (their edges collapse onto the neighbours). The hand point is moved from
# the flange to the palm, where the fingers attach, and each finger point to
# its fingertip (4.5 cm along the finger, at the TCP height) so that the jaw
# opening is drawn. README "Skeleton" has the numbers.
PALM = (0.0, 0.0, 0.0584)
FINGERTIP = (0.0, 0.0, 0.045)


class Franka(Embodiment):
    """Franka Emika Panda (7-DoF arm) with the Franka Hand parallel gripper."""

    name = "franka"
    description = "Franka Emika Panda with the Franka Hand (DROID, RH20T cfg5, InternData-A1)"
    license = "Apache-2.0"
    datasets = ("droid", "rh20t_cfg5", "interndata_a1")
    urdf = _PandaURDF()
    skeleton = Skeleton(
        links=(
            "panda_link0",
            "panda_link1",
            "panda_link3",
            "panda_link4",
            "panda_link5",
            "panda_link7",
            "panda_hand",
            "panda_leftfinger",
            "panda_rightfinger",
        ),
        points={"panda_hand": PALM, "panda_leftfinger": FINGERTIP, "panda_rightfinger": FINGERTIP},
        groups={
            "arm": ("panda_link0", "panda_link1", "panda_link3", "panda_link4", "panda_link5", "panda_link7"),
            "hand": ("panda_hand", "panda_leftfinger", "panda_rightfinger"),
        },
    )
    # Signal: finger opening width in metres, 0 (closed) .. 0.08 (open). It also
    # drives panda_finger_joint1 (0 .. 0.04 m per finger; joint2 mimics it).
    # The indicator is drawn at the flange (panda_hand's origin), above the
    # palm, so that it does not cover the jaw drawn by the fingertips.
    end_effector_links = ("panda_hand",)  # the gripper's link (latent-action baseline)
    grippers = (
        Gripper(
            "gripper",
            link="panda_hand",
            point=(0.0, 0.0, 0.0),
            signal_range=(0.0, 0.08),
            closed_at="low",
            joint="panda_finger_joint1",
            joint_range=(0.0, 0.04),
        ),
    )
    # DROID's convention (the adapters give each Camera its own direction:
    # RH20T calibrations are world_to_camera).
    camera = CameraSpec(convention="opencv", direction="camera_to_world", mount_link=None)
    example_trajectory = ASSETS / "example_trajectory.npz"
    example_camera = ASSETS / "example_camera.json"


@hookimpl
def oscar_register_embodiments():
    from .robotiq import FrankaRobotiq  # the same arm with a Robotiq 2F-85 (DROID): README "Robotiq 2F-85"

    return [Franka, FrankaRobotiq]
