"""Errors of the world model and its checkpoints.

Like every oscar error, a message names the file (or object), what was
expected and what was found.
"""

from __future__ import annotations

from ..errors import OscarError

__all__ = ["ModelInputError", "CheckpointError", "CheckpointLayoutError", "CheckpointIntegrityError"]


class ModelInputError(OscarError, ValueError):
    """Bad input to the model, the sampler or a rollout (shapes, frame counts, sizes)."""


class CheckpointError(OscarError, ValueError):
    """A checkpoint cannot be used."""


class CheckpointLayoutError(CheckpointError):
    """Files or weights a checkpoint needs are missing, unexpected or of the wrong shape.

    ``expected`` and ``found`` are kept on the exception for programs.
    """

    def __init__(self, source, what, expected, found, hint: str = ""):
        self.source, self.what, self.expected, self.found = str(source), what, expected, found
        self.hint = hint
        msg = f"{source}: {what}: expected {expected}, found {found}"
        super().__init__(msg + (f". {hint}" if hint else ""))

    def __reduce__(self):
        return (type(self), (self.source, self.what, self.expected, self.found))


class CheckpointIntegrityError(CheckpointError):
    """A checkpoint file is corrupted or partial (hash or safetensors structure mismatch)."""

    def __init__(self, path, what, expected, found, hint: str = ""):
        self.path, self.what, self.expected, self.found = str(path), what, expected, found
        msg = f"{path}: {what}: expected {expected}, found {found}"
        super().__init__(msg + (f". {hint}" if hint else ""))

    def __reduce__(self):
        return (type(self), (self.path, self.what, self.expected, self.found))
