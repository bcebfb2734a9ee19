"""Hook specifications: the public import path ``oscar_core.hookspecs`` of :mod:`oscar_core.plugin.hookspecs`
(plugins and their docs import from here)."""

from .plugin.hookspecs import *  # noqa: F403
from .plugin.hookspecs import __all__  # noqa: F401
