"""oscar-toyarm: an example embodiment plugin, written as an outside author would.

It is one module, one URDF and one entry point (see pyproject.toml):

    [project.entry-points.oscar]
    toyarm = "oscar_toyarm"
"""

from pathlib import Path

from oscar_core import CameraSpec, Embodiment, Gripper, Skeleton, hookimpl

ASSETS = Path(__file__).parent / "assets"


class ToyArm(Embodiment):
    """A 4-DoF arm (yaw, shoulder, elbow, wrist) with a two-finger gripper."""

    name = "toyarm"
    description = "4-DoF toy arm with a parallel gripper (oscar's plugin example)"
    license = "Apache-2.0"
    datasets = ()
    urdf = ASSETS / "toyarm.urdf"
    skeleton = Skeleton(
        links=("base_link", "turntable", "upper_arm", "forearm", "wrist", "tool", "left_finger", "right_finger"),
        # the fingertips, 3 cm beyond each finger's joint, make the jaw visible
        points={"left_finger": (0.0, 0.0, 0.03), "right_finger": (0.0, 0.0, 0.03)},
        groups={
            "arm": ("base_link", "turntable", "upper_arm", "forearm", "wrist"),
            "hand": ("tool", "left_finger", "right_finger"),
        },
    )
    # gripper signal: finger opening width in metres, 0 (closed) .. 0.08 (open)
    # it also drives finger_left (0 .. 0.04 m per finger; finger_right mimics it)
    end_effector_links = ("tool",)  # the gripper's link (latent-action baseline)
    grippers = (
        Gripper(
            "gripper",
            link="tool",
            point=(0.0, 0.0, 0.0),
            signal_range=(0.0, 0.08),
            closed_at="low",
            joint="finger_left",
            joint_range=(0.0, 0.04),
        ),
    )
    camera = CameraSpec(convention="opencv", direction="camera_to_world", mount_link=None)
    example_trajectory = ASSETS / "example_trajectory.npz"
    example_camera = ASSETS / "example_camera.json"


@hookimpl
def oscar_register_embodiments():
    return [ToyArm]
