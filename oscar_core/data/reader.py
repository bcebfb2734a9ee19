"""Moved to :mod:`oscar_core.plugin.reader` (the reader contract sits beside the plugin contract).

This module keeps the old import path working.
"""

from ..plugin.reader import *  # noqa: F403
from ..plugin.reader import __all__  # noqa: F401
