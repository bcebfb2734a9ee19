"""The embodiment contract: the public import path ``oscar_core.embodiment`` of :mod:`oscar_core.plugin.embodiment`
(plugins and their docs import from here)."""

from .plugin.embodiment import *  # noqa: F403
from .plugin.embodiment import __all__  # noqa: F401
