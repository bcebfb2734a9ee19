"""Kinematic trees from URDF/xacro: the public import path ``oscar_core.urdf`` of :mod:`oscar_core.kinematics.urdf`
(plugins and their docs import from here)."""

from .kinematics.urdf import *  # noqa: F403
from .kinematics.urdf import __all__  # noqa: F401
