"""A one-file oscar plugin: the SO-101 arm from the ``example-robot-data`` wheel.

Load it with ``oscar --plugin examples/one-file/so101.py …``. The URDF (with its
STL visual meshes, so the mesh condition works too) is found through the
distribution's file list, as the franka plugin finds the Panda's. Joint order
of trajectories is the URDF's document order: wrist_roll, wrist_flex,
elbow_flex, shoulder_lift, shoulder_pan (radians); the gripper signal is the
jaw opening 0 (closed) .. 1 (open), which drives the ``gripper`` joint from 0
to 1.5 rad.
"""

from importlib import metadata
from pathlib import Path

from oscar_core import Embodiment, Gripper, PluginError, Skeleton, hookimpl

SUFFIX = "so_arm_description/urdf/so101.urdf"


def so101_urdf() -> Path:
    """The SO-101 URDF inside the installed ``example-robot-data`` distribution."""
    try:
        dist = metadata.distribution("example-robot-data")
    except metadata.PackageNotFoundError:
        raise PluginError(
            "embodiment 'so101' needs the 'example-robot-data' distribution; "
            "install it with: pip install example-robot-data"
        ) from None
    for f in dist.files or ():
        if f.as_posix().endswith(SUFFIX):
            return Path(dist.locate_file(f)).resolve()
    raise PluginError(f"embodiment 'so101': example-robot-data {dist.version} has no {SUFFIX}")


class _URDF:
    def __get__(self, obj, owner=None):
        return self if obj is None else so101_urdf()


class SO101(Embodiment):
    """SO-101 (5-DoF arm and a one-jaw gripper), from example-robot-data (Apache-2.0)."""

    name = "so101"
    description = "SO-101 arm from example-robot-data (one-file plugin example)"
    license = "Apache-2.0"
    urdf = _URDF()
    skeleton = Skeleton(
        links=(
            "base_link",
            "shoulder_link",
            "upper_arm_link",
            "lower_arm_link",
            "wrist_link",
            "gripper_link",
            "moving_jaw_so101_v1_link",
        )
    )
    grippers = (
        Gripper(
            "gripper",
            link="gripper_link",
            signal_range=(0.0, 1.0),
            closed_at="low",
            joint="gripper",
            joint_range=(0.0, 1.5),
        ),
    )
    end_effector_links = ("gripper_link",)


@hookimpl
def oscar_register_embodiments():
    return [SO101]
