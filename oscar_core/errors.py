"""Errors oscar raises on bad input.

Every message names the file (or object), the field, what was expected and
what was found, so a user can fix the input without reading oscar's code.
"""

from __future__ import annotations

__all__ = [
    "OscarError",
    "InputFileError",
    "CameraFileError",
    "KinematicsFileError",
    "TrajectoryError",
    "OutputPathError",
    "PluginError",
]


class OscarError(Exception):
    """Base class of every error oscar raises on bad input."""


class InputFileError(OscarError, ValueError):
    """A file (or in-memory object standing for one) has a bad field."""

    def __init__(self, path, field, expected, found):
        self.path, self.field, self.expected, self.found = str(path), field, expected, found
        super().__init__(f"{path}: field '{field}': expected {expected}, found {found}")

    def __reduce__(self):
        return (type(self), (self.path, self.field, self.expected, self.found))


class CameraFileError(InputFileError):
    """Bad camera calibration file or dictionary."""


class KinematicsFileError(InputFileError):
    """Missing or malformed URDF / xacro description."""


class TrajectoryError(InputFileError):
    """Bad trajectory: shapes, names, non-finite values, ranges."""


class OutputPathError(OscarError, OSError):
    """An output path cannot be written."""

    def __init__(self, path, reason):
        self.path, self.reason = str(path), reason
        super().__init__(f"{path}: cannot write output: {reason}")

    def __reduce__(self):
        return (type(self), (self.path, self.reason))


class PluginError(OscarError):
    """A plugin failed to import or broke the embodiment contract."""
