"""Moved to :mod:`oscar_core.model.latent_action` (the latent-action conditioning is a model).

This module keeps the old import path working.
"""

from ..model.latent_action import *  # noqa: F403
from ..model.latent_action import __all__  # noqa: F401
