"""Cameras: conventions and rigid transforms (``geometry``), reading extrinsics (``extrinsics``), projection
(``projection``), and the :class:`Camera` with its file format (``pinhole``). ``from oscar_core.camera import
Camera`` is the public import path."""

from .pinhole import *  # noqa: F403
from .pinhole import __all__  # noqa: F401
