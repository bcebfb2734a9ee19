"""Where the Panda URDF lives: the ``example-robot-data`` distribution's file list.

Its own module so that the Franka plugin and its Robotiq variant both use it without
importing each other.
"""

from __future__ import annotations

import functools
from pathlib import Path

from oscar_core import PluginError

__all__ = ["URDF_DISTRIBUTION", "URDF_SUFFIX", "panda_urdf_path"]

URDF_DISTRIBUTION = "example-robot-data"
URDF_SUFFIX = "panda_description/urdf/panda.urdf"


@functools.cache
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
            f"which is not installed; install it with: pip install {URDF_DISTRIBUTION}"
        ) from None
    for f in dist.files or ():
        if f.as_posix().endswith(URDF_SUFFIX):
            path = Path(dist.locate_file(f)).resolve()
            if path.is_file():
                return path
    raise PluginError(
        f"embodiment 'franka': the installed '{URDF_DISTRIBUTION}' {dist.version} does not contain "
        f"'{URDF_SUFFIX}' (expected in its file list); reinstall it with: pip install --force-reinstall {URDF_DISTRIBUTION}"
    )
