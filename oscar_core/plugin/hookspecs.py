"""Hook specifications of oscar's plugin system (pluggy project ``"oscar"``).

A plugin is a module with functions marked ``@hookimpl`` whose names match the
specs below. It is found through the ``oscar`` entry-point group, or loaded
from a file path (``--plugin PATH`` / ``OSCAR_PLUGINS``).
"""

from __future__ import annotations

import pluggy

__all__ = ["hookspec", "hookimpl", "PROJECT_NAME"]

PROJECT_NAME = "oscar"

hookspec = pluggy.HookspecMarker(PROJECT_NAME)
hookimpl = pluggy.HookimplMarker(PROJECT_NAME)


@hookspec
def oscar_register_embodiments():
    """Return the embodiment classes this plugin provides.

    Called once per plugin when the registry loads. Return a list (or tuple)
    of :class:`oscar_core.Embodiment` subclasses; each declares a unique
    ``name``. Not ``firstresult``: every plugin's classes are collected, and a
    plugin that raises here is reported without stopping the others.
    """


@hookspec
def oscar_register_readers():
    """Return the dataset-reader classes this plugin provides.

    Called once per plugin when the registry loads. Return a list (or tuple)
    of :class:`oscar_core.plugin.reader.Reader` subclasses; each declares a
    unique ``name`` (``oscar data ingest SOURCE --reader NAME``). Not
    ``firstresult``: every plugin's readers are collected, and a plugin that
    raises here is reported without stopping the others.
    """
