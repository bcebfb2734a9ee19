"""Reading a JSON input file whose syntax errors name the file, the line and the column."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

__all__ = ["read_json"]


def read_json(path: str | os.PathLike, error: type) -> Any:
    """The parsed JSON document at ``path``. Invalid JSON raises ``error(path, "<document>", "valid JSON",
    "<message> at line L, column C")`` (an :class:`oscar_core.errors.InputFileError` subclass); OSError
    (e.g. FileNotFoundError) if the file cannot be read."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise error(path, "<document>", "valid JSON", f"{e.msg} at line {e.lineno}, column {e.colno}") from None
