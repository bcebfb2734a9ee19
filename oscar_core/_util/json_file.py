"""Reading a JSON input file whose syntax errors name the file, the line and the column."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

__all__ = ["read_json"]


def read_json(path: str | os.PathLike, error: type, expected: str = "JSON (utf-8 text)") -> Any:
    """The parsed JSON document at ``path``. Invalid JSON raises ``error(path, "<document>", "valid JSON",
    "<message> at line L, column C")`` (an :class:`oscar_core.errors.InputFileError` subclass); a file that is
    missing, a folder, unreadable or not utf-8 text raises ``error(path, "<file>", expected, what it is)``
    (:func:`oscar_core._util.inputs.read_text_file`)."""
    from .inputs import read_text_file

    path = Path(path)
    text = read_text_file(path, expected, error=error)
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise error(path, "<document>", "valid JSON", f"{e.msg} at line {e.lineno}, column {e.colno}") from None
