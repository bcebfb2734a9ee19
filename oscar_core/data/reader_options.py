"""A reader's constructor options from the command line: ``--reader-option NAME=VALUE``.

Readers take their documented options as constructor keywords
(``LeRobotReader(intrinsics=...)``, ``DroidRawReader(image_size=...)``,
``EgoDexReader(min_confidence=...)``). On the command line each is
``NAME=VALUE``: VALUE is read as YAML (``0.5``, ``true``, ``[1280, 720]``,
``{exterior_1_left: [130, 130, 160, 90]}``), or, when it names an existing
``.json``/``.yaml``/``.yml`` file, as that file's content
(``intrinsics=cam.json``). Names and types are checked against the reader's
constructor before any work; the options are stored in every manifest row
(column ``reader_options``), so each stage's workers build the reader the same
way ingest did.
"""

from __future__ import annotations

import inspect
import json
import math
import typing
from pathlib import Path
from typing import Any

__all__ = ["ReaderOptionError", "parse_reader_options", "reader_options", "check_reader_options"]

_FILES = (".json", ".yaml", ".yml")


class ReaderOptionError(ValueError):
    """A ``--reader-option`` is malformed, unknown to the reader, or of the wrong type."""


def parse_reader_options(items: list[str] | None) -> dict[str, Any]:
    """``["intrinsics=cam.json", "image_size=[1280, 720]"]`` → {name: value} (values read as YAML or from a file)."""
    import yaml

    out: dict[str, Any] = {}
    for item in items or ():
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name.isidentifier():
            raise ReaderOptionError(f"--reader-option: expected NAME=VALUE (e.g. intrinsics=cam.json), found {item!r}")
        if name in out:
            raise ReaderOptionError(f"--reader-option {name}: given twice")
        path = Path(text.strip())
        if path.suffix.lower() in _FILES:
            if not path.is_file():
                raise ReaderOptionError(
                    f"--reader-option {name}={text}: expected a {path.suffix} file, found no such file"
                )
            try:
                raw = path.read_text()
                out[name] = json.loads(raw) if path.suffix.lower() == ".json" else yaml.safe_load(raw)
            except (OSError, ValueError, yaml.YAMLError) as exc:
                raise ReaderOptionError(
                    f"--reader-option {name}={text}: expected {path.suffix[1:].upper()}, found "
                    f"{type(exc).__name__}: {str(exc).splitlines()[0]}"
                ) from None
        else:
            try:
                out[name] = yaml.safe_load(text)
            except yaml.YAMLError as exc:
                raise ReaderOptionError(
                    f"--reader-option {name}: expected a YAML value, found {text!r} ({str(exc).splitlines()[0]})"
                ) from None
    return out


def reader_options(cls) -> dict[str, inspect.Parameter]:
    """The keyword options a reader class takes (its constructor's parameters), by name."""
    params = inspect.signature(cls.__init__).parameters
    return {n: p for n, p in list(params.items())[1:] if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}


def check_reader_options(cls, options: dict[str, Any]) -> dict[str, Any]:
    """``options`` checked against ``cls``'s constructor: known names, values of the annotated type.

    Returns the options with lists turned into tuples where a tuple is asked
    for and integers into floats where a float is. Raises
    :class:`ReaderOptionError` naming the reader, the option, what was expected
    and what was found.
    """
    known = reader_options(cls)
    params = inspect.signature(cls.__init__).parameters.values()
    open_ended = any(p.kind is p.VAR_KEYWORD for p in params)  # a constructor taking **kwargs checks its own
    try:
        hints = typing.get_type_hints(cls.__init__)
    except Exception:  # noqa: BLE001 - an annotation that does not evaluate: check names only
        hints = {}
    out = {}
    for name, value in options.items():
        if name not in known and not open_ended:
            takes = ", ".join(sorted(known)) or "none"
            raise ReaderOptionError(
                f"--reader-option {name}: reader {cls.name!r} has no such option; it takes: {takes}"
            )
        out[name] = _typed(hints.get(name, Any), value, f"--reader-option {name} (reader {cls.name!r})")
    return out


def _typed(hint, value, where: str):
    args = typing.get_args(hint)
    if type(None) in args:
        if value is None:
            return None
        rest = [a for a in args if a is not type(None)]
        hint = rest[0] if len(rest) == 1 else typing.Union[tuple(rest)]  # noqa: UP007 - built from a tuple at run time
        args = typing.get_args(hint)
    origin = typing.get_origin(hint) or hint

    def bad(expected):
        raise ReaderOptionError(f"{where}: expected {expected}, found {type(value).__name__} {value!r}")

    if origin is Any or origin is typing.Union:
        return value
    if origin is bool:
        return value if isinstance(value, bool) else bad("true or false")
    if origin is int:
        return value if isinstance(value, int) and not isinstance(value, bool) else bad("an integer")
    if origin is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            bad("a finite number")
        return float(value)
    if origin is str:
        return value if isinstance(value, str) else bad("a string")
    if origin is dict:
        return (
            value
            if isinstance(value, dict)
            else bad("a mapping, e.g. {exterior_1_left: [fx, fy, cx, cy]} or a .json/.yaml file holding one")
        )
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            bad("a list, e.g. [1280, 720]")
        if args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                bad(f"a list of {len(args)} values")
            return tuple(_typed(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
        return tuple(value)
    if origin is list:
        return list(value) if isinstance(value, (list, tuple)) else bad("a list")
    return value
