"""oscar embodiment plugin: Franka Emika Panda with the Franka Hand.

Datasets: DROID, RH20T cfg5, InternData-A1 (adapters in
:mod:`oscar_embodiments.franka.adapters`). The kinematics are the Panda URDF
shipped in the ``example-robot-data`` wheel (Apache-2.0), found through the
distribution's file list the first time the embodiment is used, so importing
this module stays cheap. Provenance, joint order, units and conventions:
``README.md``.
"""

from __future__ import annotations

import functools
from pathlib import Path

from oscar_core import CameraSpec, Embodiment, Gripper, PluginError, Skeleton, hookimpl

__all__ = ["Franka", "ASSETS", "JOINT_NAMES", "URDF_DISTRIBUTION", "URDF_SUFFIX", "panda_urdf_path",
           "oscar_register_embodiments"]

ASSETS = Path(__file__).resolve().parent / "assets"

#: Joint order of trajectories (radians); the finger joint is driven by the gripper signal.
JOINT_NAMES = tuple(f"panda_joint{i}" for i in range(1, 8))

URDF_DISTRIBUTION = "example-robot-data"
URDF_SUFFIX = "panda_description/urdf/panda.urdf"


@functools.lru_cache(maxsize=None)
def panda_urdf_path() -> Path:
    """Absolute path of ``panda_description/urdf/panda.urdf`` inside the installed
    ``example-robot-data`` distribution (it has no Python module to import).

    Raises :class:`oscar_core.PluginError` naming the distribution if it is
    missing or does not list the file.
    """
    from importlib import metadata

    try:
        dist = metadata.distribution(URDF_DISTRIBUTION)
    except metadata.PackageNotFoundError:
        raise PluginError(
            f"embodiment 'franka' needs the Panda URDF from the '{URDF_DISTRIBUTION}' distribution, "
            f"which is not installed; install it with: pip install {URDF_DISTRIBUTION}") from None
    for f in dist.files or ():
        if f.as_posix().endswith(URDF_SUFFIX):
            path = Path(dist.locate_file(f)).resolve()
            if path.is_file():
                return path
    raise PluginError(
        f"embodiment 'franka': the installed '{URDF_DISTRIBUTION}' {dist.version} does not contain "
        f"'{URDF_SUFFIX}' (expected in its file list); reinstall it with: pip install --force-reinstall {URDF_DISTRIBUTION}")


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
        links=("panda_link0", "panda_link1", "panda_link3", "panda_link4", "panda_link5", "panda_link7",
               "panda_hand", "panda_leftfinger", "panda_rightfinger"),
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
        Gripper("gripper", link="panda_hand", point=(0.0, 0.0, 0.0), signal_range=(0.0, 0.08),
                closed_at="low", joint="panda_finger_joint1", joint_range=(0.0, 0.04)),
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
