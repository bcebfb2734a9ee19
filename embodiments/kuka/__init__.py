"""oscar embodiment plugin: KUKA LBR iiwa 14 R820 with a Robotiq 2F-85 (RH20T cfg7).

The kinematic description is a xacro written from KUKA's published
dimensions (``assets/lbr_iiwa_14_r820.urdf.xacro``); its includes are found
through ``packages`` (``$(find oscar_kuka_description)``), so no ROS is needed.
Provenance of every number, joint order, units and conventions: ``README.md``.
Dataset adapter: :mod:`oscar_embodiments.kuka.adapters` (``from_rh20t``).
"""

from pathlib import Path

from oscar_core import CameraSpec, Embodiment, Gripper, Skeleton, hookimpl

__all__ = ["KukaIiwa14", "ASSETS", "JOINT_NAMES", "oscar_register_embodiments"]

ASSETS = Path(__file__).resolve().parent / "assets"

#: Joint order of trajectories (the KUKA controller's A1..A7, radians);
#: the same names RH20T's configs.json gives for cfg6/cfg7.
JOINT_NAMES = tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8))

# Canonical points on the roll links (A1, A3, A5, A7): their link frames sit on
# the axis intersections, where the next pitch joint is, so the point is moved
# up the roll axis to the joint housing (offsets from the IFL-CAMP iiwa_stack
# iiwa14 description, README "Skeleton").
_HOUSINGS = {
    "lbr_iiwa_link_1": (0.0, 0.0, 0.1575),
    "lbr_iiwa_link_3": (0.0, 0.0, 0.2045),
    "lbr_iiwa_link_5": (0.0, 0.0, 0.1845),
    "lbr_iiwa_link_7": (0.0, 0.0, 0.081),
}


class KukaIiwa14(Embodiment):
    """LBR iiwa 14 R820 (7-DoF) with a schematic two-finger Robotiq 2F-85 jaw."""

    name = "kuka"
    description = "KUKA LBR iiwa 14 R820 with a Robotiq 2F-85 gripper (RH20T cfg7)"
    license = "Apache-2.0"
    datasets = ("rh20t_cfg7",)
    xacro = ASSETS / "lbr_iiwa_14_r820.urdf.xacro"
    xacro_args = {"axis_offset": "0.0", "palm_length": "0.10", "tool_length": "0.20"}
    packages = {"oscar_kuka_description": ASSETS}
    skeleton = Skeleton(
        links=(
            "lbr_iiwa_link_0",
            "lbr_iiwa_link_1",
            "lbr_iiwa_link_2",
            "lbr_iiwa_link_3",
            "lbr_iiwa_link_4",
            "lbr_iiwa_link_5",
            "lbr_iiwa_link_6",
            "lbr_iiwa_link_7",
            "lbr_iiwa_flange",
            "gripper_palm",
            "gripper_left_finger",
            "gripper_right_finger",
        ),
        points=_HOUSINGS,
        groups={
            "arm": (
                "lbr_iiwa_link_0",
                "lbr_iiwa_link_1",
                "lbr_iiwa_link_2",
                "lbr_iiwa_link_3",
                "lbr_iiwa_link_4",
                "lbr_iiwa_link_5",
                "lbr_iiwa_link_6",
                "lbr_iiwa_link_7",
                "lbr_iiwa_flange",
            ),
            "hand": ("gripper_palm", "gripper_left_finger", "gripper_right_finger"),
        },
    )
    # Robotiq position: 0 = open, 1 = closed (Robotiq's 0..255 position byte
    # divided by 255). It drives the schematic fingertips; the indicator is
    # drawn on the fixed palm frame, behind the jaw, so it does not cover it.
    end_effector_links = ("gripper_palm",)  # the gripper's link (latent-action baseline)
    grippers = (
        Gripper(
            "gripper",
            link="gripper_palm",
            point=(0.0, 0.0, 0.0),
            signal_range=(0.0, 1.0),
            closed_at="high",
            joint="gripper_finger_joint",
            joint_range=(0.0, 0.0425),
        ),
    )
    # RH20T calibrations map robot-base points into the OpenCV camera frame.
    camera = CameraSpec(convention="opencv", direction="world_to_camera", mount_link=None)
    example_trajectory = ASSETS / "example_trajectory.npz"
    example_camera = ASSETS / "example_camera.json"


@hookimpl
def oscar_register_embodiments():
    return [KukaIiwa14]
