"""Moved to :mod:`oscar_core.reader` (the reader contract sits beside the plugin contract).

This module keeps the old import path working.
"""

from ..reader import *  # noqa: F401,F403
from ..reader import __all__  # noqa: F401
