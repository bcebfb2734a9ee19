"""A sub-command's ``--help`` shows its own examples, not its whole group's.

The command groups keep one examples block (``examples:`` then lines
``  oscar GROUP COMMAND ...``, continuation lines indented further) that each
of their sub-commands takes as its epilog. :func:`own_examples` keeps, in a
leaf parser's epilog, the example entries whose command is that parser's
``prog`` (``oscar toyworld generate``), with their continuation lines; the
text around the block stays. An epilog with no entry for the parser is left
whole (it is not a group's list).
"""

from __future__ import annotations

import argparse
import shlex

__all__ = ["own_examples", "filter_examples", "example_command"]

#: Options of the top-level ``oscar`` that may stand before the sub-command, and whether they take a value.
_GLOBAL = {
    "--plugin": True,
    "-v": False,
    "-vv": False,
    "--verbose": False,
    "-q": False,
    "-qq": False,
    "--quiet": False,
    "--no-progress": False,
}


def example_command(line: str) -> str | None:
    """The sub-command an example line runs (``"oscar toyworld generate"``), or None for a line that is not one.

    Leading ``NAME=value`` environment settings and the global options of ``oscar`` are skipped."""
    try:
        words = shlex.split(line.strip().split("   (")[0].rstrip("\\"), posix=True)
    except ValueError:
        words = line.split()
    while words and "=" in words[0] and not words[0].startswith("-"):
        words = words[1:]
    if not words or words[0] != "oscar":
        return None
    out, rest = ["oscar"], words[1:]
    while rest and rest[0] in _GLOBAL:
        rest = rest[2:] if _GLOBAL[rest[0]] else rest[1:]
    for w in rest:
        if w.startswith("-") or w in ("...", "…"):
            break
        out.append(w)
    return " ".join(out)


def _matches(command: str | None, prog: str) -> bool:
    return command is not None and (command == prog or command.startswith(prog + " "))


def filter_examples(epilog: str, prog: str) -> str:
    """``epilog`` with only ``prog``'s example entries kept (see the module); unchanged when it has none."""
    lines = epilog.splitlines()
    entries: list[tuple[int, int, bool]] = []  # (first line, end line, matches) of each example entry
    k = 0
    while k < len(lines):
        line = lines[k]
        cmd = example_command(line) if line.startswith("  ") and not line.startswith("    ") else None
        if cmd is None:
            k += 1
            continue
        end = k + 1
        while end < len(lines) and lines[end].startswith("    ") and example_command(lines[end]) is None:
            end += 1
        entries.append((k, end, _matches(cmd, prog)))
        k = end
    if not any(m for _, _, m in entries):
        return epilog
    drop = {i for a, b, m in entries if not m for i in range(a, b)}
    return "\n".join(line for i, line in enumerate(lines) if i not in drop) + ("\n" if epilog.endswith("\n") else "")


def own_examples(parser: argparse.ArgumentParser) -> None:
    """Filter the epilog of every leaf sub-command under ``parser`` (in place)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        if parser.epilog:
            parser.epilog = filter_examples(parser.epilog, parser.prog)
        return
    seen = set()
    for action in subs:
        for child in action.choices.values():
            if id(child) not in seen:
                seen.add(id(child))
                own_examples(child)
