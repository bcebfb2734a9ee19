"""Trajectories: the public import path ``oscar_core.trajectory`` of :mod:`oscar_core.kinematics.trajectory`
(plugins and their docs import from here)."""

from .kinematics.trajectory import *  # noqa: F403
from .kinematics.trajectory import __all__  # noqa: F401
